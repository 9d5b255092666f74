"""ATI Net F/T Raw Data Transfer (RDT) protocol over UDP: requests, records, and the
bookkeeping of a record stream. No sockets here: the driver node (``vibrissa.nodes.netft``)
and the simulated device (``vibrissa.wire.netft_device``) do the I/O.

The protocol (ATI Net F/T manual, "Raw Data Transfer"; the same on Axia and OnRobot HEX):

* the client sends the sensor's UDP port 49152 an 8-byte request ``>HHI``: header 0x1234,
  command, sample count (0: until stopped). Commands: 0x0000 stop, 0x0002 real-time stream
  (one record per datagram), 0x0003 buffered stream (several records per datagram), 0x0042
  set software bias (the sensor zeroes its output at the current load).
* the sensor answers with datagrams of 36-byte records ``>III6i``: ``rdt_sequence`` (records
  sent since the request, from 1), ``ft_sequence`` (the sensor's internal sample counter),
  ``status`` (0 = healthy), then Fx, Fy, Fz, Tx, Ty, Tz in counts, in the sensor frame S.
  Force = counts / counts_per_force (``cfgcpf`` in the sensor's ``netftapi2.xml``), torque =
  counts / counts_per_torque (``cfgcpt``).

`StreamTracker` turns datagrams into the records to publish and counts what happened on the
way: every ``rdt_sequence`` (32 bits, rolling over) between the first and the newest is
received, lost, or ``reordered`` (it came after a newer one: not published, the driver never
goes back in time, and not lost); a datagram that is not whole records, or a record whose
sequence lies outside any plausible window, is ``malformed``. Nothing here raises on bytes
from the network.
"""

from __future__ import annotations

import enum
import struct
import urllib.request
import xml.etree.ElementTree as ET
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

__all__ = [
    "HEADER",
    "MAX_RECORDS_PER_DATAGRAM",
    "RDT_PORT",
    "RECORD",
    "REQUEST",
    "Command",
    "NetFTConfig",
    "Records",
    "StreamTracker",
    "pack_records",
    "pack_request",
    "parse_config",
    "parse_datagram",
    "parse_request",
    "read_config",
    "to_si",
]

RDT_PORT = 49152
"""The sensor's RDT port."""

HEADER = 0x1234
REQUEST = struct.Struct(">HHI")
RECORD = struct.Struct(">III6i")
MAX_RECORDS_PER_DATAGRAM = 40
"""The Net F/T's largest RDT buffer (``comrdtbsiz``); a longer datagram is malformed."""

_RECORD_DTYPE = np.dtype([("rdt", ">u4"), ("ft", ">u4"), ("status", ">u4"), ("counts", ">i4", (6,))])

_HALF = 1 << 31
_MOD = 1 << 32


class Command(enum.IntEnum):
    """RDT request commands."""

    STOP = 0x0000
    REALTIME = 0x0002
    BUFFERED = 0x0003
    BIAS = 0x0042


def pack_request(command: Command | int, count: int = 0) -> bytes:
    """The 8-byte request ``>HHI`` (header 0x1234, command, sample count; 0 = until stopped)."""
    return REQUEST.pack(HEADER, int(command), int(count))


def parse_request(data: bytes) -> tuple[Command, int] | None:
    """``(command, count)`` of a request, or ``None`` for anything else (a device ignores it)."""
    if len(data) != REQUEST.size:
        return None
    header, command, count = REQUEST.unpack(data)
    if header != HEADER or command not in Command._value2member_map_:
        return None
    return Command(command), count


@dataclass(frozen=True)
class Records:
    """Records of one or more datagrams: ``rdt`` (N,) and ``ft`` (N,) uint32 sequences,
    ``status`` (N,) uint32, ``counts`` (N, 6) int64 Fx Fy Fz Tx Ty Tz in counts (sensor frame
    S), ``t_receive`` (N,) s of the host clock, ``t_sensor`` (N,) s (see `StreamTracker`)."""

    rdt: npt.NDArray[np.int64]
    ft: npt.NDArray[np.int64]
    status: npt.NDArray[np.int64]
    counts: npt.NDArray[np.int64]
    t_receive: npt.NDArray[np.float64]
    t_sensor: npt.NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.rdt)


def pack_records(rdt: npt.ArrayLike, ft: npt.ArrayLike, status: npt.ArrayLike,
                 counts: npt.ArrayLike) -> bytes:
    """One datagram of records: ``rdt``, ``ft``, ``status`` (N,) and ``counts`` (N, 6)
    (wrapped to 32 bits as the sensor's counters are)."""
    counts = np.asarray(counts, dtype=np.int64).reshape(-1, 6)
    out = np.empty(len(counts), dtype=_RECORD_DTYPE)
    out["rdt"] = np.asarray(rdt, dtype=np.int64) % _MOD
    out["ft"] = np.asarray(ft, dtype=np.int64) % _MOD
    out["status"] = np.asarray(status, dtype=np.int64) % _MOD
    out["counts"] = counts
    return out.tobytes()


def parse_datagram(data: bytes, max_records: int = MAX_RECORDS_PER_DATAGRAM
                   ) -> npt.NDArray[np.void] | None:
    """The records of a datagram as a structured array (fields ``rdt``, ``ft``, ``status``,
    ``counts``), or ``None`` when it is not 1 to ``max_records`` whole 36-byte records."""
    n, rest = divmod(len(data), RECORD.size)
    if rest or not 1 <= n <= max_records:
        return None
    return np.frombuffer(data, dtype=_RECORD_DTYPE)


def to_si(counts: npt.ArrayLike, counts_per_force: float, counts_per_torque: float
          ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Force (N, 3) N and torque (N, 3) N m from counts (N, 6), in the sensor frame S."""
    c = np.asarray(counts, dtype=np.float64).reshape(-1, 6)
    return c[:, :3] / counts_per_force, c[:, 3:] / counts_per_torque


def _delta(a: int, b: int) -> int:
    """``a - b`` of two 32-bit counters, in [-2^31, 2^31): the rollover undone."""
    return (a - b + _HALF) % _MOD - _HALF


@dataclass
class StreamTracker:
    """The bookkeeping of one RDT stream: which records to publish, what was lost, reordered,
    malformed, whether the sensor stalled, what its status words said.

    Parameters
    ----------
    ft_rate_hz
        Rate of the sensor's internal counter ``ft_sequence``, Hz: the sensor time of a record
        is ``ft_sequence / ft_rate_hz`` (unwrapped), mapped onto the host clock (below).
    stall_s
        The stream counts as stalled when no record arrived, or ``ft_sequence`` did not move,
        for this long, s.
    window
        Records that may arrive late (after a newer one) and still be told from loss; also
        the farthest plausible jump of ``rdt_sequence`` is ``max_gap``.
    max_gap
        A record more than this ahead of the newest is not plausible (garbage, another
        stream): ``malformed``.
    fault_mask
        Status bits that mean a fault (the sensor's data are not to be used: the record is
        counted, not published); any other set bit is a warning (published, counted).
    max_records
        Most records in a datagram.

    Sensor time. ``t_sensor = ft_sequence / ft_rate_hz + offset``, where ``offset`` keeps
    the sensor time at or below every receive time (the lower envelope of ``t_receive -
    ft/ft_rate``: a datagram is never received before it was measured): the stamps are as
    regular as the sensor's clock, on the host's time axis, and never in the future. When the
    offset moves down, the stamps wait (repeat) rather than go back before those given out.

    Counters: ``received`` (records accepted, in order, to publish), ``lost`` (gaps in
    ``rdt_sequence`` not filled since), ``reordered`` (records that came after a newer one:
    dropped, not lost), ``duplicates`` (or older than the stream's first record),
    ``malformed`` (datagrams that are not whole records, records outside the window),
    ``stalls`` (times the stream stalled), ``status_warnings``
    (records with a warning bit: published), ``status_faults`` (with a fault bit: dropped),
    ``datagrams``. Over one stream (between two `restart` calls), with ``first`` and
    ``newest`` its first and newest accepted ``rdt_sequence`` (unwrapped)::

        received + status_faults + lost + reordered == newest - first + 1
    """

    ft_rate_hz: float = 7000.0
    stall_s: float = 0.2
    window: int = 4096
    max_gap: int = 1 << 20
    fault_mask: int = 0x80000000
    max_records: int = MAX_RECORDS_PER_DATAGRAM
    counters: dict[str, int] = field(default_factory=dict)
    last_status: int = 0
    _newest: int | None = None       # unwrapped rdt_sequence of the newest accepted record
    _missing: OrderedDict[int, None] = field(default_factory=OrderedDict)
    _ft_last: int | None = None      # unwrapped ft_sequence of the newest record
    _ft_moved_at: float | None = None
    heard_at: float | None = None    # receive time of the newest accepted record
    _offset: float | None = None
    _last_stamp: float = -np.inf
    stalled: bool = False

    COUNTERS = ("datagrams", "received", "lost", "reordered", "duplicates", "malformed",
                "stalls", "status_warnings", "status_faults")

    def __post_init__(self) -> None:
        for name in self.COUNTERS:
            self.counters.setdefault(name, 0)

    def restart(self, now: float) -> None:
        """A new stream was requested (the sensor starts ``rdt_sequence`` again at 1): forget
        the sequences, keep the counters and a stall (it ends with the first moving record);
        the stall clock starts at ``now``."""
        self._newest = None
        self._missing.clear()
        self._ft_last = None
        self._offset = None
        self.heard_at = None
        self._ft_moved_at = now

    def feed(self, data: bytes, t_receive: float) -> Records:
        """The records of one datagram to publish, in order (maybe none); counts the rest.
        A datagram is a batch of one: `feed_many`."""
        return self.feed_many((data,), t_receive)

    def feed_many(self, datagrams: Sequence[bytes], t_receive: float) -> Records:
        """The records of datagrams received together (in arrival order, at ``t_receive``) to
        publish, in order (maybe none); counts the rest, as `feed` of each in turn would.

        The bytes of the whole datagrams are joined and parsed in one ``frombuffer``, and the
        stamps computed for the batch with numpy: the per-datagram cost of a realtime stream
        (a record per datagram) is then a few list operations, not a dozen numpy calls."""
        c = self.counters
        c["datagrams"] += len(datagrams)
        whole: list[bytes] = []
        group: list[int] = []  # datagram (index in ``whole``) of each record
        for data in datagrams:
            n, rest = divmod(len(data), RECORD.size)
            if rest or not 1 <= n <= self.max_records:
                c["malformed"] += 1
                continue
            group += [len(whole)] * n
            whole.append(data)
        if not whole:
            return _EMPTY
        records = np.frombuffer(b"".join(whole), dtype=_RECORD_DTYPE)
        keep: list[int] = []
        ft_out: list[int] = []
        starts: list[int] = []  # where in ``keep`` each datagram's kept records start
        last_group = -1
        for i, (rdt, ft, status) in enumerate(zip(records["rdt"].tolist(), records["ft"].tolist(),
                                                  records["status"].tolist(), strict=True)):
            if self._newest is None:
                self._newest = rdt
            else:
                d = _delta(rdt, self._newest % _MOD)
                if d > self.max_gap or d < -self.window:
                    c["malformed"] += 1
                    continue
                if d <= 0:  # older than the newest: late (reordered) or a duplicate
                    late = self._newest + d
                    if late in self._missing:
                        del self._missing[late]
                        c["lost"] -= 1
                        c["reordered"] += 1
                    else:
                        c["duplicates"] += 1
                    continue
                if d > 1:
                    self._missing.update(dict.fromkeys(range(self._newest + 1, self._newest + d)))
                    while len(self._missing) > self.window:
                        self._missing.popitem(last=False)  # too old to come: lost for good
                    c["lost"] += d - 1
                self._newest += d
            self.heard_at = t_receive
            ft_u = ft if self._ft_last is None else self._ft_last + _delta(ft, self._ft_last % _MOD)
            if ft_u != self._ft_last:
                self._ft_moved_at = t_receive
                self.stalled = False
            self._ft_last = ft_u
            self.last_status = status
            if status & self.fault_mask:
                c["status_faults"] += 1
                continue
            if status:
                c["status_warnings"] += 1
            if group[i] != last_group:
                last_group = group[i]
                starts.append(len(keep))
            keep.append(i)
            ft_out.append(ft_u)
        n = len(keep)
        c["received"] += n
        if not n:
            return _EMPTY
        kept = records[keep]
        t_ft = np.asarray(ft_out, dtype=np.float64) / self.ft_rate_hz
        # Each datagram moves the offset down to its newest record's (as fed one by one);
        # every record of a datagram gets its datagram's offset.
        offset_g = np.minimum.accumulate(t_receive - np.maximum.reduceat(t_ft, starts))
        if self._offset is not None:
            offset_g = np.minimum(offset_g, self._offset)
        self._offset = float(offset_g[-1])
        offset = np.repeat(offset_g, np.diff([*starts, n]))
        # a lower offset must not send the stamps back before those already given out
        t_sensor = np.maximum.accumulate(np.maximum(t_ft + offset, self._last_stamp))
        self._last_stamp = float(t_sensor[-1])
        return Records(
            rdt=kept["rdt"].astype(np.int64), ft=kept["ft"].astype(np.int64),
            status=kept["status"].astype(np.int64), counts=kept["counts"].astype(np.int64),
            t_receive=np.full(n, t_receive), t_sensor=t_sensor)

    def check_stall(self, now: float) -> bool:
        """Whether the stream is stalled at ``now`` (no record, or ``ft_sequence`` frozen, for
        ``stall_s``); counts each stall once, when it begins."""
        since = self._ft_moved_at
        if since is None or self.stalled:
            return self.stalled
        if now - since >= self.stall_s:
            self.stalled = True
            self.counters["stalls"] += 1
        return self.stalled


_EMPTY = Records(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64),
                 np.zeros((0, 6), dtype=np.int64), np.zeros(0), np.zeros(0))


@dataclass(frozen=True)
class NetFTConfig:
    """What the driver needs from the sensor's configuration: counts per force unit and per
    torque unit (``cfgcpf``, ``cfgcpt``), the units' names (``scfgfu``, ``scfgtu``) and the
    RDT output rate (``comrdtrate``, Hz; 0 when not given)."""

    counts_per_force: float
    counts_per_torque: float
    force_unit: str = "N"
    torque_unit: str = "Nm"
    rdt_rate_hz: float = 0.0


_TO_NEWTON = {"N": 1.0, "kN": 1e3, "mN": 1e-3}
_TO_NEWTON_METRE = {"Nm": 1.0, "N-m": 1.0, "Nmm": 1e-3, "N-mm": 1e-3, "kNm": 1e3}


def parse_config(xml_text: str | bytes) -> NetFTConfig:
    """`NetFTConfig` from the text of ``netftapi2.xml``, counts per N and per N m.

    Raises
    ------
    ValueError
        Not XML, a missing or non-positive ``cfgcpf``/``cfgcpt``, or a unit other than N,
        kN, mN and N m, N mm, kN m (lbf and lbf-in sensors: set the counts by hand).
    """
    try:
        root = ET.fromstring(xml_text)
    except ET.ParseError as exc:
        raise ValueError(f"netftapi2.xml: not XML: {exc}") from None

    def text(tag: str) -> str | None:
        node = root.find(f".//{tag}")
        return None if node is None or node.text is None else node.text.strip()

    values = {}
    for tag in ("cfgcpf", "cfgcpt"):
        raw = text(tag)
        try:
            values[tag] = float(raw) if raw is not None else float("nan")
        except ValueError:
            values[tag] = float("nan")
        if not values[tag] > 0:
            raise ValueError(f"netftapi2.xml: {tag} must be a number > 0, got {raw!r}")
    force_unit, torque_unit = text("scfgfu") or "N", text("scfgtu") or "Nm"
    if force_unit not in _TO_NEWTON or torque_unit not in _TO_NEWTON_METRE:
        raise ValueError(f"netftapi2.xml: units {force_unit!r}, {torque_unit!r}: only "
                         f"{sorted(_TO_NEWTON)} and {sorted(_TO_NEWTON_METRE)} are converted")
    try:
        rate = float(text("comrdtrate") or 0.0)
    except ValueError:
        rate = 0.0
    # counts per unit -> counts per N: a count of 1 unit is 1 / cpf unit = to_si / cpf N.
    return NetFTConfig(values["cfgcpf"] / _TO_NEWTON[force_unit],
                       values["cfgcpt"] / _TO_NEWTON_METRE[torque_unit],
                       force_unit, torque_unit, rate)


def read_config(address: str, timeout_s: float = 2.0, port: int = 80) -> NetFTConfig:
    """`parse_config` of ``http://address:port/netftapi2.xml`` (``OSError`` when unreachable)."""
    url = f"http://{address}:{port}/netftapi2.xml"
    with urllib.request.urlopen(url, timeout=timeout_s) as response:  # noqa: S310 - http only
        return parse_config(response.read())
