"""MCAP bags of wire messages: write, read (also when cut off mid-write), summarise, export.

A bag stores the exact codec payload of every message (``message_encoding="msgpack"``), one
channel per topic and one schema per message type: schema ``name`` is the type's ``TYPE_NAME``,
``encoding="jsonschema"``, ``data`` the type's JSON schema with its wire version under
``"x-vibrissa-version"``. Times are integer nanoseconds since the Unix epoch.

Chunks are small (``chunk_size`` bytes, ``max_chunk_messages`` messages or ``flush_interval_s``
seconds, whichever comes first) and each finished chunk is flushed to the file, so a recorder
that dies loses at most the chunk in progress; :class:`BagReader` reads such a cut-off bag up
to its last complete record and reports how many bytes it could not use.
"""

from __future__ import annotations

import contextlib
import heapq
import io
import itertools
import json
import logging
import math
import os
import struct
import threading
import time
import zlib
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Any, NamedTuple

import zmq
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, ChunkIndex, DataEnd, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader, breakup_chunk, get_chunk_data_stream
from mcap.summary import Summary
from mcap.writer import CompressionType, Writer

from vibrissa.msgs import EndOfStream, codec
from vibrissa.msgs import Message as WireMessage
from vibrissa.wire.transport import Endpoints, MessageTypes, Publisher
from vibrissa.wire.waiting import wait_event

__all__ = [
    "BagDamage",
    "BagInfo",
    "BagReader",
    "BagRecord",
    "BagWriter",
    "PACE_EVERY",
    "PlayResult",
    "check_bag_file",
    "TopicInfo",
    "export_json",
    "play_bag",
]

log = logging.getLogger(__name__)

MSGPACK_ENCODING = "msgpack"
JSON_ENCODING = "json"
SCHEMA_ENCODING = "jsonschema"
VERSION_KEY = "x-vibrissa-version"
PACE_EVERY = 250
"""Messages between two calls of `play_bag`'s ``pace`` when played as fast as possible."""
_MAGIC = b"\x89MCAP0\r\n"
_FOOTER = struct.Struct("<BQQQI")  # opcode, length, summary_start, summary_offset_start, crc
_PROFILE = ""  # no well-known profile fits; Foxglove reads jsonschema + json without one

# What a cut-off or corrupted record can raise while being parsed: a short read (EndOfFile,
# struct.error), a garbled length or string (McapError, ValueError incl. a chunk CRC
# mismatch), or a truncated zstd/lz4 frame (their own exception types; caught by name below).
_DAMAGE_ERRORS: tuple[type[BaseException], ...] = (McapError, struct.error, ValueError, EOFError)
try:  # the mcap package needs zstandard; import it the same way it does
    import zstandard

    _DAMAGE_ERRORS = (*_DAMAGE_ERRORS, zstandard.ZstdError)
except ImportError:  # pragma: no cover
    pass


class BagRecord(NamedTuple):
    """One message read back from a bag.

    ``payload`` is the exact codec bytes that were on the wire; ``type_name`` the schema name
    (the message type's ``TYPE_NAME``); times in ns since the Unix epoch; ``sequence`` the
    publisher's per-topic counter when the recorder knew it, else 0.
    """

    topic: str
    log_time_ns: int
    type_name: str
    payload: bytes
    publish_time_ns: int
    sequence: int


@dataclass(frozen=True)
class BagDamage:
    """What a read of a bag could not use: chunks skipped as unreadable, a tail cut off (no
    complete record after it), and their bytes. False when nothing was lost."""

    damaged_chunks: int = 0
    truncated: bool = False
    unreadable_bytes: int = 0

    def __bool__(self) -> bool:
        return bool(self.damaged_chunks or self.truncated)

    def note(self, lost: str) -> str:
        """One line on the loss; ``lost`` ends it: "their messages not {lost}" ("played")."""
        what = [f"{self.damaged_chunks} damaged chunk(s) skipped"] if self.damaged_chunks else []
        what += ["cut off at the end"] if self.truncated else []
        return (f"{', '.join(what)}; {self.unreadable_bytes} unreadable bytes, their messages "
                f"not {lost}")


@dataclass(frozen=True)
class TopicInfo:
    """Message count and type of one topic in a bag."""

    topic: str
    type_name: str
    count: int


@dataclass(frozen=True)
class BagInfo:
    """Summary of a bag.

    ``start_ns``/``end_ns`` are the first and last log times (ns, Unix epoch; 0 when empty),
    ``duration_s`` their difference in seconds. Every chunk was read (decompressed, its CRC
    checked): ``damaged_chunks`` did not read; ``truncated`` is True when the file has no valid
    summary and could be read only up to some record (the writer was cut off);
    ``unreadable_bytes`` counts both. ``summary_damaged``: a finished file whose summary section
    (the index other readers seek through) does not read or match its CRC; its data was read
    without it. The counts and times are those of the readable messages.
    """

    path: str
    size_bytes: int
    message_count: int
    start_ns: int
    end_ns: int
    topics: tuple[TopicInfo, ...]
    types: dict[str, int]
    chunk_count: int
    damaged_chunks: int
    truncated: bool
    unreadable_bytes: int
    summary_damaged: bool = False

    @property
    def damage(self) -> BagDamage:
        """What of the bag could not be read."""
        return BagDamage(self.damaged_chunks, self.truncated, self.unreadable_bytes)

    @property
    def topic_counts(self) -> dict[str, int]:
        """Messages per topic, all types together."""
        out: dict[str, int] = {}
        for t in self.topics:
            out[t.topic] = out.get(t.topic, 0) + t.count
        return out

    @property
    def duration_s(self) -> float:
        """Time from first to last message, s."""
        return (self.end_ns - self.start_ns) * 1e-9

    def format(self) -> str:
        """Human-readable multi-line summary (what ``vibrissa bag info`` prints)."""
        lines = [
            f"path:      {self.path}",
            f"size:      {self.size_bytes} bytes",
            f"messages:  {self.message_count}",
            f"duration:  {self.duration_s:.3f} s",
        ]
        if self.message_count:
            lines.append(f"start:     {_format_time(self.start_ns)} ({self.start_ns} ns)")
            lines.append(f"end:       {_format_time(self.end_ns)} ({self.end_ns} ns)")
        lines.append(f"chunks:    {self.chunk_count}")
        integrity = (self.damage.note("counted") if self.damage else
                     "intact, every chunk decompressed and its CRC checked")
        if self.summary_damaged:  # the data was read without it
            integrity = ("summary section damaged (it does not read or match its CRC: readers "
                         "that seek through its index may fail or miss messages); the data, "
                         f"read without it: {integrity}")
        lines.append(f"integrity: {integrity}")
        width = max([len(t.topic) for t in self.topics] + [5])
        lines.append("topics:")
        for t in self.topics:
            lines.append(f"  {t.topic:<{width}}  {t.count:>8} msgs  {t.type_name}")
        lines.append("types:")
        for name, count in sorted(self.types.items()):
            lines.append(f"  {name:<{width}}  {count:>8} msgs")
        return "\n".join(lines)


def _format_time(t_ns: int) -> str:
    seconds, ns = divmod(t_ns, 1_000_000_000)
    stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(seconds))
    return f"{stamp}.{ns // 1000:06d} UTC"


def _schema_json(type_name: str, version: int) -> dict[str, Any]:
    """JSON schema of a message type, with the wire version; minimal if the type or its
    version is unknown (e.g. an older version's payloads, replayed and recorded again)."""
    cls = codec.MESSAGE_TYPES.get(type_name)
    known = cls is not None and cls.VERSION == version
    schema: dict[str, Any] = dict(codec.json_schema(cls)) if known else {}  # type: ignore[arg-type]
    schema.setdefault("title", type_name)
    schema.setdefault("type", "object")
    schema[VERSION_KEY] = version
    return schema


class BagWriter(contextlib.AbstractContextManager["BagWriter"]):
    """Write codec payloads to an MCAP file in small, individually flushed chunks.

    Parameters
    ----------
    path
        Output ``.mcap`` file (overwritten).
    chunk_size
        Finish a chunk once its uncompressed size exceeds this many bytes.
    max_chunk_messages
        Finish a chunk once it holds this many messages.
    flush_interval_s
        Finish the chunk in progress on the next :meth:`write` or :meth:`flush_if_due` once
        it is older than this, s; bounds what a crash loses on a slow topic.
    message_encoding
        ``"msgpack"`` for codec payloads; :func:`export_json` uses ``"json"``.
    compression
        Chunk compression; zstd by default (Foxglove reads it).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        chunk_size: int = 64 * 1024,
        max_chunk_messages: int = 256,
        flush_interval_s: float = 1.0,
        message_encoding: str = MSGPACK_ENCODING,
        compression: CompressionType = CompressionType.ZSTD,
    ) -> None:
        if chunk_size <= 0:
            raise ValueError(f"chunk_size must be > 0 bytes, got {chunk_size}")
        if max_chunk_messages <= 0:
            raise ValueError(f"max_chunk_messages must be > 0, got {max_chunk_messages}")
        self.path = Path(path)
        self._message_encoding = message_encoding
        self._max_chunk_messages = max_chunk_messages
        self._flush_interval_s = flush_interval_s
        self._file: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=compression)
        self._writer.start(profile=_PROFILE, library="vibrissa")
        self._file.flush()
        self._schemas: dict[tuple[str, int], int] = {}
        self._channels: dict[tuple[str, int], int] = {}
        self._pending = 0
        self._chunk_started = time.monotonic()
        self._closed = False
        self.message_count = 0

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc is None:
            self.close()
            return
        # Writing failed (e.g. a full disk): closing may fail the same way; the error that
        # matters is the first, and the bag stays readable up to its last complete chunk.
        with contextlib.suppress(Exception):
            self.close()

    def register_schema(self, type_name: str, version: int, schema: dict[str, Any]) -> int:
        """Register ``schema`` for (type, version) once; return its MCAP schema id."""
        key = (type_name, version)
        if key not in self._schemas:
            data = json.dumps(schema, sort_keys=True, separators=(",", ":")).encode()
            self._schemas[key] = self._writer.register_schema(
                name=type_name, encoding=SCHEMA_ENCODING, data=data
            )
        return self._schemas[key]

    def _channel_id(self, topic: str, schema_id: int) -> int:
        key = (topic, schema_id)
        if key not in self._channels:
            self._channels[key] = self._writer.register_channel(
                topic=topic, message_encoding=self._message_encoding, schema_id=schema_id
            )
        return self._channels[key]

    def write(
        self,
        topic: str,
        payload: bytes,
        log_time_ns: int,
        publish_time_ns: int | None = None,
        sequence: int = 0,
    ) -> None:
        """Append one codec payload, stored byte for byte.

        Parameters
        ----------
        topic
            Absolute topic name.
        payload
            ``codec.encode(msg)`` bytes; the type and version are read from it.
        log_time_ns
            Receive time, ns since the Unix epoch.
        publish_time_ns
            Send time, ns; defaults to ``log_time_ns``.
        sequence
            Publisher sequence number from the wire header (stored modulo 2**32).
        """
        type_name, version = codec.peek_type(payload)
        schema_id = self.register_schema(type_name, version, _schema_json(type_name, version))
        self._write(topic, schema_id, payload, log_time_ns, publish_time_ns, sequence)

    def _write(
        self,
        topic: str,
        schema_id: int,
        data: bytes,
        log_time_ns: int,
        publish_time_ns: int | None,
        sequence: int,
    ) -> None:
        if self._closed:
            raise ValueError(f"bag {self.path} is closed")
        channel_id = self._channel_id(topic, schema_id)
        self._writer.add_message(
            channel_id=channel_id,
            log_time=int(log_time_ns),
            data=bytes(data),
            publish_time=int(log_time_ns if publish_time_ns is None else publish_time_ns),
            sequence=int(sequence) & 0xFFFFFFFF,
        )
        self.message_count += 1
        if self._pending == 0:
            self._chunk_started = time.monotonic()
        self._pending += 1
        if self._pending >= self._max_chunk_messages:
            self.flush()
        else:
            self.flush_if_due()

    def flush(self) -> None:
        """Finish the chunk in progress and push it to the OS (no fsync)."""
        self._writer.flush()
        self._pending = 0

    def flush_if_due(self) -> None:
        """Flush if the chunk in progress is older than ``flush_interval_s``; cheap to poll."""
        if self._pending and time.monotonic() - self._chunk_started >= self._flush_interval_s:
            self.flush()

    def close(self) -> None:
        """Write the summary and footer and close the file; idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
        finally:
            self._file.close()


def check_bag_file(path: str | os.PathLike[str]) -> Path:
    """``path`` as a ``Path`` if it is a file that starts as an MCAP file does (or as much of
    that start as the file holds).

    Raises
    ------
    FileNotFoundError
        Nothing (or no file) at ``path``.
    ValueError
        A file that is not MCAP (empty, or its first bytes are not the MCAP magic).
    """
    file = Path(path)
    if not file.is_file():
        raise FileNotFoundError(f"no bag at {file}" + (" (a folder)" if file.is_dir() else ""))
    with open(file, "rb") as f:
        head = f.read(len(_MAGIC))
    if not head:
        raise ValueError(f"{file} is empty (0 bytes), not an MCAP file")
    if head != _MAGIC[: len(head)]:  # a shorter head is a bag cut off at its very start
        raise ValueError(f"{file} is not an MCAP file (it does not start with the MCAP magic)")
    return file


class BagReader:
    """Read a bag written by :class:`BagWriter`, also one that was cut off mid-write.

    Iterating yields :class:`BagRecord` in log-time order: through the chunk index for a
    finished bag; for a cut-off bag (no footer) by streaming through the file, each chunk
    sorted, up to the last complete chunk. After a full iteration, ``truncated`` and
    ``unreadable_bytes`` tell whether and how much of the file's tail was lost, and
    ``damaged_chunks`` how many chunks of a finished bag were skipped as unreadable (their bytes
    count in ``unreadable_bytes``; the messages around them are all read, none twice);
    :attr:`damage` holds the three, :meth:`report_damage` says them. ``summary_damaged``: the
    file is finished but its summary section does not read or match its CRC, so it is read as
    a cut-off one is (streamed), which loses nothing.

    Parameters
    ----------
    path
        ``.mcap`` file.
    topics
        Only these topics; all when None.
    """

    def __init__(self, path: str | os.PathLike[str], topics: Iterable[str] | None = None):
        self.path = check_bag_file(path)
        self.topics = None if topics is None else frozenset(topics)
        self.truncated = False
        self.unreadable_bytes = 0
        self.damaged_chunks = 0
        self.summary_damaged = False

    def __iter__(self) -> Iterator[BagRecord]:
        return self.records()

    @property
    def damage(self) -> BagDamage:
        """What the last full iteration (or :meth:`info`) could not read."""
        return BagDamage(self.damaged_chunks, self.truncated, self.unreadable_bytes)

    def report_damage(self, lost: str) -> BagDamage:
        """After a full iteration: log a warning of one line when something could not be read
        (``lost`` ends it: "their messages not {lost}"), and return :attr:`damage`."""
        damage = self.damage
        if damage:
            log.warning("%s: %s", self.path, damage.note(lost))
        return damage

    def is_finished(self) -> bool:
        """True when the file ends with a footer and the closing magic bytes."""
        size = self.path.stat().st_size
        if size < 2 * len(_MAGIC) + 29:  # magic, footer record (1 + 8 + 20 bytes), magic
            return False
        with open(self.path, "rb") as f:
            f.seek(-len(_MAGIC), io.SEEK_END)
            return f.read(len(_MAGIC)) == _MAGIC

    def records(self) -> Iterator[BagRecord]:
        """Yield every readable message (see class docstring)."""
        self.truncated = False
        self.unreadable_bytes = 0
        self.damaged_chunks = 0
        summary = self._summary()
        if summary is not None and summary.chunk_indexes:
            yield from self._indexed(summary)
        else:
            yield from self._streamed()

    def _summary(self) -> Summary | None:
        """The summary section of a finished bag; None when there is none, or when it does
        not read or match the footer's CRC (``summary_damaged``): the file is streamed then."""
        self.summary_damaged = False
        if not self.is_finished():
            return None
        try:
            with open(self.path, "rb") as f:
                if _summary_crc_matches(f):
                    f.seek(0)
                    return SeekingReader(f).get_summary()
        except _DAMAGE_ERRORS:
            pass
        self.summary_damaged = True
        return None

    def topic_names(self) -> list[str]:
        """Every topic of the bag (whatever ``topics`` keeps), sorted: the channels of its
        summary, or of the messages that read."""
        summary = self._summary()
        if summary is not None:
            return sorted({channel.topic for channel in summary.channels.values()})
        return sorted({record.topic for record in BagReader(self.path)})

    def _keep(self, topic: str) -> bool:
        return self.topics is None or topic in self.topics

    def _indexed(self, summary: Summary) -> Iterator[BagRecord]:
        """Chunk by chunk through the index, in log-time order: a damaged chunk is skipped
        and counted (``damaged_chunks``, its bytes in ``unreadable_bytes``), the chunks
        after it are read as if nothing happened."""
        chunks = sorted(summary.chunk_indexes,
                        key=lambda c: (c.message_start_time, c.chunk_start_offset))
        pending: list[tuple[int, int, BagRecord]] = []  # a heap by (log time, arrival)
        order = itertools.count()
        with open(self.path, "rb") as f:
            for i, index in enumerate(chunks):
                try:
                    records = self._chunk_records(f, index, summary)
                except _DAMAGE_ERRORS:
                    self.damaged_chunks += 1
                    self.unreadable_bytes += index.chunk_length
                    continue
                for record in records:
                    heapq.heappush(pending, (record.log_time_ns, next(order), record))
                # everything before the next chunk's first message is in order now
                bound = chunks[i + 1].message_start_time if i + 1 < len(chunks) else None
                while pending and (bound is None or pending[0][0] < bound):
                    yield heapq.heappop(pending)[2]
        while pending:  # held back for a last chunk that turned out damaged
            yield heapq.heappop(pending)[2]

    def _chunk_records(self, f: IO[bytes], index: ChunkIndex, summary: Summary
                       ) -> list[BagRecord]:
        """The kept messages of one chunk, in file order (raises one of ``_DAMAGE_ERRORS``
        when the chunk does not read or its CRC does not match)."""
        out = []
        for record in breakup_chunk(_read_chunk(f, index), validate_crc=True):
            if isinstance(record, McapMessage):
                channel = summary.channels.get(record.channel_id)
                if channel is not None and self._keep(channel.topic):
                    out.append(_record(summary.schemas.get(channel.schema_id), channel, record))
        return out

    def _streamed(self) -> Iterator[BagRecord]:
        size = self.path.stat().st_size
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        with open(self.path, "rb") as f:
            stream = StreamReader(f, emit_chunks=True, validate_crcs=False).records
            good_end = 0  # offset just past the last record parsed in full
            finished = data_end = False
            while True:
                try:
                    record = next(stream)
                except StopIteration:
                    finished = True
                    break
                except _DAMAGE_ERRORS:
                    # after the data of a finished file whose summary is damaged, nothing lost
                    finished = data_end and self.summary_damaged
                    break
                batch: list[Schema | Channel | McapMessage] = []
                if isinstance(record, Chunk):
                    try:
                        batch = [
                            r
                            for r in breakup_chunk(record, validate_crc=True)
                            if isinstance(r, (Schema, Channel, McapMessage))
                        ]
                    except _DAMAGE_ERRORS:
                        break
                elif isinstance(record, (Schema, Channel, McapMessage)):
                    batch = [record]
                data_end = data_end or isinstance(record, DataEnd)
                good_end = f.tell()
                messages: list[BagRecord] = []
                for r in batch:
                    if isinstance(r, Schema):
                        schemas[r.id] = r
                    elif isinstance(r, Channel):
                        channels[r.id] = r
                    elif r.channel_id in channels:
                        channel = channels[r.channel_id]
                        if self._keep(channel.topic):
                            messages.append(_record(schemas.get(channel.schema_id), channel, r))
                messages.sort(key=lambda m: m.log_time_ns)  # stable: keeps file order on ties
                yield from messages
        if not finished:
            self.truncated = True
            self.unreadable_bytes = size - good_end

    def info(self) -> BagInfo:
        """Summarise the bag: counts per topic and type, first/last log time, damage.

        Every chunk is decompressed and its CRC checked (no message is parsed); the counts and
        times come from the summary's statistics when all chunks read, else from reading every
        readable message (also with ``topics``: the statistics have no per-topic times).
        """
        counts: Counter[tuple[str, str]] = Counter()
        start_ns, end_ns, n = 0, 0, 0
        summary = self._summary()
        stats = None if summary is None else summary.statistics
        if (summary is not None and stats is not None and self.topics is None
                and self._chunks_read(summary)):
            for channel_id, count in stats.channel_message_counts.items():
                channel = summary.channels[channel_id]
                schema = summary.schemas.get(channel.schema_id)
                counts[(channel.topic, schema.name if schema else "")] += count
            n = sum(counts.values())
            start_ns, end_ns = stats.message_start_time, stats.message_end_time
            self.truncated, self.unreadable_bytes, self.damaged_chunks = False, 0, 0
        else:
            first = True
            for rec in self.records():
                counts[(rec.topic, rec.type_name)] += 1
                n += 1
                if first:
                    start_ns = end_ns = rec.log_time_ns
                    first = False
                start_ns = min(start_ns, rec.log_time_ns)
                end_ns = max(end_ns, rec.log_time_ns)
        topics = tuple(
            TopicInfo(topic=t, type_name=ty, count=c) for (t, ty), c in sorted(counts.items())
        )
        types: Counter[str] = Counter()
        for (_, ty), c in counts.items():
            types[ty] += c
        return BagInfo(
            path=str(self.path),
            size_bytes=self.path.stat().st_size,
            message_count=n,
            start_ns=start_ns,
            end_ns=end_ns,
            topics=topics,
            types=dict(types),
            chunk_count=self._count_chunks() if stats is None else stats.chunk_count,
            damaged_chunks=self.damaged_chunks,
            truncated=self.truncated,
            unreadable_bytes=self.unreadable_bytes,
            summary_damaged=self.summary_damaged,
        )

    def _chunks_read(self, summary: Summary) -> bool:
        """Whether every chunk of the index decompresses and matches its CRC (a chunk without
        a CRC, which :class:`BagWriter` never writes, is only decompressed)."""
        with open(self.path, "rb") as f:
            for index in summary.chunk_indexes:
                try:
                    get_chunk_data_stream(_read_chunk(f, index), validate_crc=True)
                except _DAMAGE_ERRORS:
                    return False
        return True

    def _count_chunks(self) -> int:
        n = 0
        with open(self.path, "rb") as f:
            stream = StreamReader(f, emit_chunks=True).records
            try:
                for record in stream:
                    n += isinstance(record, Chunk)
            except _DAMAGE_ERRORS:
                pass
        return n


def _summary_crc_matches(f: IO[bytes]) -> bool:
    """Whether the footer's ``summary_crc`` (0: none written) is the CRC-32 of the summary
    section and the footer up to it (the MCAP specification); raises ``McapError`` when the
    footer is not one."""
    size = os.fstat(f.fileno()).st_size
    f.seek(size - len(_MAGIC) - _FOOTER.size)
    opcode, length, summary_start, _, crc = _FOOTER.unpack(f.read(_FOOTER.size))
    if opcode != Opcode.FOOTER or length != _FOOTER.size - 9 or summary_start > size:
        raise McapError("no footer before the closing magic")
    if crc == 0:
        return True
    f.seek(summary_start or size - len(_MAGIC) - _FOOTER.size)
    end, computed = size - len(_MAGIC) - 4, 0
    while f.tell() < end:
        computed = zlib.crc32(f.read(min(1 << 20, end - f.tell())), computed)
    return computed == crc


def _read_chunk(f: IO[bytes], index: ChunkIndex) -> Chunk:
    """The chunk record ``index`` points to, still compressed (raises one of
    ``_DAMAGE_ERRORS`` when it does not parse or runs past the end of the file)."""
    if index.chunk_start_offset + index.chunk_length > os.fstat(f.fileno()).st_size:
        raise EOFError(f"chunk at {index.chunk_start_offset} runs past the end of the file")
    f.seek(index.chunk_start_offset)
    raw = f.read(index.chunk_length)
    if len(raw) != index.chunk_length:
        raise EOFError(f"chunk at {index.chunk_start_offset} runs past the end of the file")
    chunk = next(StreamReader(io.BytesIO(raw), skip_magic=True, emit_chunks=True).records, None)
    if not isinstance(chunk, Chunk):
        raise McapError(f"no chunk at offset {index.chunk_start_offset}")
    return chunk


def _record(schema: Schema | None, channel: Channel, message: McapMessage) -> BagRecord:
    return BagRecord(
        topic=channel.topic,
        log_time_ns=message.log_time,
        type_name=schema.name if schema is not None else "",
        payload=message.data,
        publish_time_ns=message.publish_time,
        sequence=message.sequence,
    )


def export_json(
    src: str | os.PathLike[str], dst: str | os.PathLike[str], topics: Iterable[str] | None = None
) -> tuple[BagInfo, BagDamage]:
    """Convert a msgpack bag into a JSON-encoded MCAP that Foxglove opens.

    Every payload is decoded with the codec and written as ``codec.to_jsonable`` JSON
    (``message_encoding="json"``, arrays as nested lists), with the type's JSON schema
    (``encoding="jsonschema"``) and the original log/publish times. A damaged or cut-off source
    is exported as far as it reads. Returns the info of the written file and what of ``src``
    could not be read (also logged as a warning, see :meth:`BagReader.report_damage`).
    """
    reader = BagReader(src, topics=topics)
    with BagWriter(dst, message_encoding=JSON_ENCODING, flush_interval_s=math.inf) as out:
        for rec in reader:
            msg = codec.decode(rec.payload)  # a retired type's payload: as the type it decodes to
            type_name, version = msg.TYPE_NAME, msg.VERSION
            schema_id = out.register_schema(type_name, version, _schema_json(type_name, version))
            data = json.dumps(codec.to_jsonable(msg), allow_nan=False).encode()
            out._write(rec.topic, schema_id, data, rec.log_time_ns, rec.publish_time_ns,
                       rec.sequence)
    return BagReader(dst).info(), reader.report_damage("exported")


@dataclass
class PlayResult:
    """What :func:`play_bag` published: counts per topic, wall time in s, stopped early."""

    published: dict[str, int] = field(default_factory=dict)
    wall_s: float = 0.0
    interrupted: bool = False

    @property
    def total(self) -> int:
        """Messages published on all topics."""
        return sum(self.published.values())


def play_bag(
    path: str | os.PathLike[str],
    *,
    rate: float | None = 1.0,
    topics: Iterable[str] | None = None,
    wait_s: float = 1.0,
    endpoints: Endpoints | None = None,
    context: zmq.Context[Any] | None = None,
    stop: threading.Event | None = None,
    make_publisher: Callable[[str, MessageTypes, int], Publisher] | None = None,
    ready: Callable[[dict[str, Publisher]], bool] | None = None,
    drain_s: float = 2.0,
    pace: Callable[[int], bool] | None = None,
) -> PlayResult:
    """Publish a bag's messages with their original bytes (``publish_raw``) and timing.

    Order is kept per topic (one publisher socket each, whatever the types on it: a topic
    with several message types gets one publisher of all of them, and each payload goes out
    with its own type); across topics it follows from the timing, so ``rate=None`` may
    interleave topics differently from the bag.

    Parameters
    ----------
    path
        Bag to play.
    rate
        Time scale: 1.0 real time, 2.0 twice as fast; None publishes as fast as possible.
    topics
        Only these topics; all when None.
    wait_s
        Seconds to wait after creating the publishers before the first message, so that
        subscriptions reach them through the proxy (ZeroMQ's slow joiner).
    endpoints, context
        For the default publishers; ``Endpoints.from_env()`` and the global context if None.
    stop
        Set it to stop early (e.g. from a signal handler).
    make_publisher
        ``f(topic, msg_type, hwm) -> Publisher``, e.g. ``Node.create_publisher`` with a
        readiness gate; ``msg_type`` is the topic's data type, or a tuple of them when the
        bag holds several on it. The caller then owns (closes) the publishers.
    ready
        Called with the ``{topic: Publisher}`` map after ``wait_s``, before the first
        message; may block (e.g. until readiness gates open) and returns False to abort.
    drain_s
        Linger of the default publishers at close, s: queued messages get this long to
        leave once the context terminates.
    pace
        With ``rate=None``: called with the number of messages published so far every
        `PACE_EVERY` messages, before the next; may block until the subscribers caught up
        (messages beyond a subscriber's queue in the proxy are dropped) and returns False to
        stop.
    """
    if rate is not None and not (rate > 0 and math.isfinite(rate)):
        raise ValueError(f"rate must be finite and > 0, or None (as fast as possible), got {rate}")
    stop = stop if stop is not None else threading.Event()
    reader = BagReader(path, topics=topics)
    info = reader.info()
    counts = info.topic_counts
    result = PlayResult(published={t: 0 for t in counts})
    topic_types: dict[str, list[type[WireMessage]]] = {}
    for t in info.topics:
        msg_type = codec.decodes_as(t.type_name)  # a retired type: the one that replaced it
        if msg_type is None:
            raise ValueError(f"{path}: topic {t.topic} has unknown message type {t.type_name!r}")
        types = topic_types.setdefault(t.topic, [])
        if msg_type not in types:
            types.append(msg_type)
    own = make_publisher is None

    def default_publisher(topic: str, msg_type: MessageTypes, hwm: int) -> Publisher:
        return Publisher(topic, msg_type, endpoints=endpoints, context=context, hwm=hwm)

    make = make_publisher or default_publisher
    publishers: dict[str, Publisher] = {}
    try:
        for topic, types in topic_types.items():
            # EndOfStream, which any publisher may send, only counts on a topic without data
            data = tuple(t for t in types if t is not EndOfStream) or (EndOfStream,)
            # the high-water mark holds the whole topic so that rate=None drops nothing here
            publishers[topic] = make(topic, data[0] if len(data) == 1 else data,
                                     max(1000, counts[topic] + 1))
        if stop.wait(max(0.0, wait_s)) or (ready is not None and not ready(publishers)):
            result.interrupted = True
            return result
        t_wall0 = time.monotonic()
        t_bag0: int | None = None
        sent = 0
        for rec in reader:
            if t_bag0 is None:
                t_bag0 = rec.log_time_ns
            if rate is not None:
                due = t_wall0 + (rec.log_time_ns - t_bag0) * 1e-9 / rate
                if wait_event(stop, due - time.monotonic()):
                    result.interrupted = True
                    break
            elif stop.is_set() or (pace is not None and sent and not sent % PACE_EVERY
                                   and not pace(sent)):
                result.interrupted = True
                break
            publishers[rec.topic].publish_raw(rec.payload)
            result.published[rec.topic] += 1
            sent += 1
        result.wall_s = time.monotonic() - t_wall0
        reader.report_damage("played")
        return result
    finally:
        if own:
            for pub in publishers.values():
                pub.close(linger_s=drain_s)
