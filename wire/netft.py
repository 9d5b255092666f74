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
goes back in time, and not lost); a datagram that is not whole records is ``malformed``; a
record whose sequences jump where no sensor's can is a ``sequence_anomalies`` (the stream
resynchronises at once). Nothing here raises on bytes from the network.
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
    "CALIBRATION_RANGE",
    "HEADER",
    "MAX_RECORDS_PER_DATAGRAM",
    "RDT_PORT",
    "RECORD",
    "REQUEST",
    "Command",
    "NetFTConfig",
    "Records",
    "StreamTracker",
    "calibration_error",
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
    malformed or implausible, whether the sensor stalled, what its status words said.

    Parameters
    ----------
    ft_rate_hz
        Rate of the sensor's internal counter ``ft_sequence``, Hz: the sensor time of a record
        is ``ft_sequence / ft_rate_hz`` (unwrapped), mapped onto the host clock (below). No
        sensor sends records faster.
    stall_s
        The stream counts as stalled when no record arrived, or ``ft_sequence`` did not move,
        for this long, s.
    window
        Records that may arrive late (after a newer one) and still be told from loss.
    slack_s
        How far, s, a record's sequences may run ahead of the host clock (below).
    fault_mask
        Status bits that mean a fault (the sensor's data are not to be used: the record is
        counted, not published); any other set bit is a warning (published, counted).
    max_records
        Most records in a datagram.

    Sensor time. ``t_sensor = ft_sequence / ft_rate_hz + offset``, where ``offset`` keeps
    the sensor time at or below every receive time (the lower envelope of ``t_receive -
    ft/ft_rate``: a datagram is never received before it was measured): the stamps are as
    regular as the sensor's clock, on the host's time axis, and never in the future. When the
    offset moves down, the stamps do not go back: they advance at half the sensor's pace until
    they meet it again, so the stamps of published records strictly increase.

    Implausible jumps. A record is measured before it is received, and the sensor makes at
    most ``ft_rate_hz`` records a second: a newer record whose ``ft_sequence`` goes back, or
    whose sensor time or ``rdt_sequence`` is ahead of what the time since the newest record
    allows (``slack_s`` for latency and host-clock steps; plus ``window`` records), is not
    the stream's. It is counted in ``sequence_anomalies`` and dropped; when the next record
    follows on from it rather than from the stream, the sensor's counters did jump: the
    stream resynchronises at that record (a new offset, the stamps still increasing), else
    the stream goes on as if the wild record had not come (it counts as lost).

    Counters: ``received`` (records accepted, in order, to publish), ``lost`` (gaps in
    ``rdt_sequence`` not filled since), ``reordered`` (records that came after a newer one:
    dropped, not lost), ``duplicates`` (or older than the stream's first record),
    ``malformed`` (datagrams that are not whole records), ``sequence_anomalies`` (records
    with an implausible jump: dropped), ``ft_frozen`` (records whose ``ft_sequence`` did not
    move: a stalled sensor's, dropped), ``stalls`` (times the stream stalled),
    ``status_warnings`` (records with a warning bit: published), ``status_faults`` (with a
    fault bit: dropped), ``datagrams``. Over one stream without jumps (between two `restart`
    calls), with ``first`` and ``newest`` its first and newest accepted ``rdt_sequence``
    (unwrapped)::

        received + status_faults + ft_frozen + lost + reordered == newest - first + 1
    """

    ft_rate_hz: float = 7000.0
    stall_s: float = 0.2
    window: int = 4096
    slack_s: float = 1.0
    fault_mask: int = 0x80000000
    max_records: int = MAX_RECORDS_PER_DATAGRAM
    counters: dict[str, int] = field(default_factory=dict)
    last_status: int = 0
    _newest: int | None = None       # unwrapped rdt_sequence of the newest accepted record
    _missing: OrderedDict[int, None] = field(default_factory=OrderedDict)
    _ft_last: int | None = None      # unwrapped ft_sequence of the newest record
    _ft_moved_at: float | None = None
    heard_at: float | None = None    # receive time of the newest accepted record
    _offset: float = np.inf          # the stream's offset (lower envelope), s
    _ft_stamped: int | None = None   # unwrapped ft_sequence of the last record stamped
    _last_stamp: float = -np.inf
    _suspect: tuple[int, int, float] | None = None  # (rdt, ft, offset) of a wild record
    _restarted: bool = False         # a new stream requested, its first record not yet here
    stalled: bool = False

    COUNTERS = ("datagrams", "received", "lost", "reordered", "duplicates", "malformed",
                "sequence_anomalies", "ft_frozen", "stalls", "status_warnings", "status_faults")

    def __post_init__(self) -> None:
        for name in self.COUNTERS:
            self.counters.setdefault(name, 0)

    def restart(self, now: float) -> None:
        """A new stream was requested (the sensor starts ``rdt_sequence`` again at 1): keep
        the counters and a stall (it ends with the first moving record); the stall clock starts
        at ``now``. Records that follow on from the old stream's newest are the old stream's,
        sent before the request arrived (in order: published); the first that does not (an
        ``rdt_sequence`` at or below the old newest) begins the new stream."""
        self._restarted = self._newest is not None
        self._suspect = None
        self.heard_at = None
        self._ft_moved_at = now

    def _rebase(self, rdt: int, ft: int | None, offset: float) -> None:
        """Take ``rdt``, ``ft`` as the stream's newest record, with the sensor time's
        ``offset``: the sequences start again there (the stamps go on increasing)."""
        self._newest, self._ft_last, self._offset = rdt, ft, offset
        self._missing.clear()
        self._ft_stamped = None
        self._suspect = None

    def _follows(self, d_rdt: int, ft_ref: int, ft_u: int, offset: float, t_receive: float
                 ) -> bool:
        """Whether a record ``d_rdt`` after a reference record (``ft_sequence`` ``ft_ref``,
        its sensor time's ``offset``), with ``ft_sequence`` ``ft_u`` (unwrapped, not behind
        ``ft_ref``), received at ``t_receive``, can be the same stream's (see the class doc)."""
        rate = self.ft_rate_hz
        since_s = t_receive - (ft_ref / rate + offset) + self.slack_s  # since ft_ref, at most
        ahead_s = ft_u / rate + offset - t_receive  # how far the record is after its receipt
        return 0 < d_rdt <= self.window + since_s * rate and ahead_s <= self.slack_s

    def feed(self, data: bytes, t_receive: float) -> Records:
        """The records of one datagram to publish, in order (maybe none); counts the rest.
        A datagram is a batch of one: `feed_many`."""
        return self.feed_many((data,), t_receive)

    def feed_many(self, datagrams: Sequence[bytes], t_receive: float) -> Records:
        """The records of datagrams received together (in arrival order, at ``t_receive``) to
        publish, in order (maybe none); counts the rest, as `feed` of each in turn would.

        The bytes of the whole datagrams are joined and parsed in one ``frombuffer``: the
        per-datagram cost of a realtime stream (a record per datagram) is a few list and
        float operations, not a dozen numpy calls."""
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
        rate = self.ft_rate_hz
        keep: list[int] = []
        stamps: list[float] = []
        # kept records of the current datagram: (sensor time, floor step) until its offset is known
        waiting: list[tuple[float, float]] = []
        last_group = 0

        def stamp() -> None:
            """Stamp the datagram's waiting records with the offset after its last record
            (every record of a datagram gets its datagram's offset)."""
            last = self._last_stamp
            for t_ft, step in waiting:
                last = max(t_ft + self._offset, last + step)
                stamps.append(last)
            self._last_stamp = last
            waiting.clear()

        for i, (rdt, ft, status) in enumerate(zip(records["rdt"].tolist(), records["ft"].tolist(),
                                                  records["status"].tolist(), strict=True)):
            if group[i] != last_group:
                stamp()
                last_group = group[i]
            if self._newest is None or (
                    self._restarted and _delta(rdt, self._newest % _MOD) <= 0):
                self._rebase(rdt, None, np.inf)  # the stream's first record
                self._restarted = False
                ft_u = ft
            else:
                d = _delta(rdt, self._newest % _MOD)
                if -self.window <= d <= 0:  # older than the newest: late (reordered) or a duplicate
                    late = self._newest + d
                    if late in self._missing:
                        del self._missing[late]
                        c["lost"] -= 1
                        c["reordered"] += 1
                    else:
                        c["duplicates"] += 1
                    continue
                assert self._ft_last is not None
                ft_u = self._ft_last + _delta(ft, self._ft_last % _MOD)
                if ft_u < self._ft_last or not self._follows(d, self._ft_last, ft_u, self._offset,
                                                             t_receive):
                    suspect = self._suspect
                    d_s = 0 if suspect is None else _delta(rdt, suspect[0])
                    ft_s = 0 if suspect is None else _delta(ft, suspect[1])
                    if suspect is None or ft_s <= 0 or not self._follows(
                            d_s, suspect[1], suspect[1] + ft_s, suspect[2], t_receive):
                        c["sequence_anomalies"] += 1
                        self._suspect = (rdt, ft, t_receive - ft / rate)
                        continue
                    # it follows on from the wild record: the sensor's counters jumped
                    stamp()
                    self._rebase(suspect[0], suspect[1], suspect[2])
                    d, ft_u = d_s, suspect[1] + ft_s
                self._suspect = None
                if d > 1:
                    self._missing.update(dict.fromkeys(range(self._newest + 1, self._newest + d)))
                    while len(self._missing) > self.window:
                        self._missing.popitem(last=False)  # too old to come: lost for good
                    c["lost"] += d - 1
                self._newest += d
            self.heard_at = t_receive
            if ft_u != self._ft_last:
                self._ft_moved_at = t_receive
                self.stalled = False
            else:  # the same sample again: a stalled sensor's
                c["ft_frozen"] += 1
                continue
            self._ft_last = ft_u
            self._offset = min(self._offset, t_receive - ft_u / rate)
            self.last_status = status
            if status & self.fault_mask:
                c["status_faults"] += 1
                continue
            if status:
                c["status_warnings"] += 1
            step = 0.5 / rate * (1 if self._ft_stamped is None else ft_u - self._ft_stamped)
            self._ft_stamped = ft_u
            waiting.append((ft_u / rate, step))
            keep.append(i)
        stamp()
        n = len(keep)
        c["received"] += n
        if not n:
            return _EMPTY
        kept = records[keep]
        return Records(
            rdt=kept["rdt"].astype(np.int64), ft=kept["ft"].astype(np.int64),
            status=kept["status"].astype(np.int64), counts=kept["counts"].astype(np.int64),
            t_receive=np.full(n, t_receive), t_sensor=np.array(stamps))

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


CALIBRATION_RANGE = {"force": (0.1, 3e9), "torque": (0.1, 4e11)}
"""Plausible counts per N (``force``) and per N m (``torque``) of a Net F/T calibration.

A count is a 32-bit integer (at most 2^31, about 2.1e9) that must reach the transducer's
full scale, and a count is finer than its resolution. ATI's smallest full scales are about
8 N and 0.05 N m (Nano17 Titanium): at most 2.1e9 / 8 = 2.7e8 counts per N and 2.1e9 / 0.05
= 4.3e10 per N m; its largest (Omega331) are tens of kN and kN m resolved to about 1 N and
1 N m: at least about 1 count per N and per N m. ATI's usual metric calibration is 1e6 per N
and per N m. The ranges hold those bounds with a factor of 10 to spare; a value outside (a
typo, a corrupted configuration: 1e-300 makes a full-scale count 2e309 N, inf makes every
force 0) is refused."""


def calibration_error(kind: str, counts_per_unit: float) -> str | None:
    """Why ``counts_per_unit`` (counts per N for ``kind`` ``force``, per N m for
    ``torque``) is not a plausible calibration (`CALIBRATION_RANGE`), or ``None``."""
    low, high = CALIBRATION_RANGE[kind]
    if low <= counts_per_unit <= high:  # also False for NaN
        return None
    unit = "N" if kind == "force" else "N m"
    return (f"{counts_per_unit!r} counts per {unit} is not a plausible {kind} calibration "
            f"(a Net F/T's lie within {low:g} to {high:g} counts per {unit})")


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
        Not XML, a missing or implausible ``cfgcpf``/``cfgcpt`` (`CALIBRATION_RANGE`), or a
        unit other than N, kN, mN and N m, N mm, kN m (lbf and lbf-in sensors: set the
        counts by hand).
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
    config = NetFTConfig(values["cfgcpf"] / _TO_NEWTON[force_unit],
                         values["cfgcpt"] / _TO_NEWTON_METRE[torque_unit],
                         force_unit, torque_unit, rate)
    for tag, kind, per_si, unit in (("cfgcpf", "force", config.counts_per_force, force_unit),
                                    ("cfgcpt", "torque", config.counts_per_torque, torque_unit)):
        error = calibration_error(kind, per_si)
        if error is not None:
            raise ValueError(f"netftapi2.xml: {tag} {text(tag)} per {unit}: {error}")
    return config


def read_config(address: str, timeout_s: float = 2.0, port: int = 80) -> NetFTConfig:
    """`parse_config` of ``http://address:port/netftapi2.xml`` (``OSError`` when unreachable)."""
    url = f"http://{address}:{port}/netftapi2.xml"
    with urllib.request.urlopen(url, timeout=timeout_s) as response:  # noqa: S310 - http only
        return parse_config(response.read())
