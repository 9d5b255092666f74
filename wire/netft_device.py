"""A simulated ATI Net F/T on a UDP socket: answers RDT requests (stream, stop, bias) with
records of a given wrench signal, with noise, bias, drift, loss and reordering, seeded.

The signal is what the sensor measures, in its frame S (N, N m; see
``vibrissa.calibration.clamp_to_sensor`` for a simulated whisker's). The device knows what it
did to the stream (``DeviceStats``: records made, dropped, sent late), so that a test can
compare the driver's counts with the truth. Faults on demand: ``freeze_ft`` (records keep
coming, ``ft_sequence`` stops: a stalled sensor), ``glitch`` (one record with wild
sequences), ``jump_ft`` (``ft_sequence`` jumps and runs on from there), ``mute`` (nothing
sent), ``send_raw`` (any datagram to the client), ``close`` and a new device on the same port
(a reboot). Counts saturate at the 32-bit limits, as a real sensor's.
"""

from __future__ import annotations

import collections
import contextlib
import socket
import threading
import time
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from vibrissa.wire.netft import Command, pack_records, parse_request

__all__ = ["DeviceStats", "NetFTDevice", "SignalSpec"]

_INT32_MIN, _INT32_MAX = -(1 << 31), (1 << 31) - 1


@dataclass(frozen=True)
class SignalSpec:
    """What the device adds to the true wrench (each of the 6 components, N or N m).

    ``noise`` Gaussian standard deviation; ``bias`` a constant offset; ``drift`` an offset
    growing per second of stream; ``loss``, ``reorder``: probability that a datagram is
    dropped, or held back and sent after the next one; ``seed`` of all of it."""

    noise: tuple[float, float] = (0.0, 0.0)          # (force N, torque N m)
    bias: tuple[float, ...] = (0.0,) * 6
    drift: tuple[float, ...] = (0.0,) * 6             # per second
    loss: float = 0.0
    reorder: float = 0.0
    seed: int = 0


@dataclass
class DeviceStats:
    """What the device did: records made (``made``, by ``rdt_sequence``), records dropped
    and records sent after a newer one (``late``; one held back when the device closes is
    neither sent nor late, but counted here until then), requests by command, bias requests
    applied."""

    made: int = 0
    dropped: int = 0
    late: int = 0
    requests: dict[str, int] = field(default_factory=dict)
    biases: int = 0


class NetFTDevice:
    """A Net F/T on ``host:port`` (port 0: a free one, ``address`` says which).

    Parameters
    ----------
    wrench_S
        (N, 6) the true load on the sensor, N and N m, one row per record; the stream holds
        the last row after the end (a rod at rest), or loops with ``loop``.
    rate_hz
        Records per second (the Net F/T goes up to 7000).
    counts_per_force, counts_per_torque
        Counts per N and per N m.
    per_datagram
        Records per datagram in buffered mode (command 0x0003).
    ft_step
        ``ft_sequence`` advance per record (the sensor's internal rate / RDT rate); it runs on
        between streams, as the sensor's internal counter does.
    emitted
        When given, each record made appends ``(row of wrench_S, time it was measured on
        time.time())`` to it (whether sent, dropped or muted): what a simulated world (the
        robot's poses) needs to go with the records.
    """

    def __init__(self, wrench_S: npt.ArrayLike, rate_hz: float = 1000.0, *,
                 counts_per_force: float = 1e6, counts_per_torque: float = 1e6,
                 spec: SignalSpec = SignalSpec(), per_datagram: int = 10, ft_step: int = 1,
                 loop: bool = False, host: str = "127.0.0.1", port: int = 0,
                 first_rdt: int = 1, first_ft: int = 0,
                 emitted: collections.deque[tuple[int, float]] | None = None) -> None:
        self.wrench_S = np.asarray(wrench_S, dtype=float).reshape(-1, 6)
        if not len(self.wrench_S):
            raise ValueError("wrench_S must have at least one row of 6")
        self.rate_hz = float(rate_hz)
        self.scale = np.array([counts_per_force] * 3 + [counts_per_torque] * 3)
        self.spec = spec
        self.per_datagram = per_datagram
        self.ft_step = ft_step
        self.loop = loop
        self.stats = DeviceStats()
        self.loss, self.reorder = spec.loss, spec.reorder  # may be changed while it runs
        self.freeze_ft = False
        self.mute = False
        self.status = 0
        self._first_rdt, self._ft = first_rdt, first_ft
        self._rng = np.random.default_rng(spec.seed)
        self._bias_counts = np.zeros(6, dtype=np.int64)
        self._last_raw = np.zeros(6, dtype=np.int64)
        self._lock = threading.Lock()
        self._client: tuple[str, int] | None = None
        self._buffered = False
        self._remaining = 0          # records left in this stream (0 with count 0: no limit)
        self._limited = False
        self._index = 0              # row of wrench_S of the next record
        self._rdt = first_rdt
        self._t0 = 0.0
        self._t0_wall = 0.0
        self._last_made: float | None = None  # monotonic time the newest record was measured
        self.emitted = emitted
        self._made_in_stream = 0
        self._held: bytes | None = None
        self._glitch = (0, 0)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, port))
        self.sock.settimeout(0.0005)
        self.address: tuple[str, int] = self.sock.getsockname()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name="netft-device")
        self._thread.start()

    # -- control -------------------------------------------------------------------------

    def glitch(self, rdt: int = 0, ft: int = 0) -> None:
        """The next record goes out with its ``rdt_sequence`` and ``ft_sequence`` off by
        these (once; the record after it is the sensor's own again)."""
        with self._lock:
            self._glitch = (rdt, ft)

    def jump_ft(self, delta: int) -> None:
        """``ft_sequence`` jumps by ``delta`` (back when negative) and runs on from there."""
        with self._lock:
            self._ft += delta

    def send_raw(self, data: bytes) -> None:
        """Send any datagram to the streaming client (a malformed one, for tests)."""
        with self._lock:
            if self._client is not None:
                self.sock.sendto(data, self._client)

    @property
    def streaming(self) -> bool:
        return self._client is not None

    def close(self) -> None:
        """Stop and close the socket (a device that reboots: make a new one on the port)."""
        self._stop.set()
        self._thread.join(2.0)
        self.sock.close()

    def __enter__(self) -> NetFTDevice:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the device ----------------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data, sender = self.sock.recvfrom(64)
            except (TimeoutError, BlockingIOError):
                data = b""
            except OSError:
                if self._stop.is_set():
                    return
                data = b""
            if data:
                self._request(data, sender)
            self._stream()

    def _request(self, data: bytes, sender: tuple[str, int]) -> None:
        parsed = parse_request(data)
        if parsed is None:
            return  # a real Net F/T ignores what it does not understand
        command, count = parsed
        self.stats.requests[command.name] = self.stats.requests.get(command.name, 0) + 1
        with self._lock:
            if command is Command.STOP:
                self._flush_held(late=False)
                self._client = None
            elif command is Command.BIAS:
                self._bias_counts = self._last_raw.copy()  # the load now reads zero
                self.stats.biases += 1
            else:
                self._flush_held(late=False)
                self._client = sender
                self._buffered = command is Command.BUFFERED
                self._limited, self._remaining = count > 0, count
                self._rdt = self._first_rdt  # rdt_sequence starts again with each request
                self._t0, self._t0_wall = time.monotonic(), time.time()
                if self._last_made is not None and not self.freeze_ft:  # the sensor's counter ran
                    self._ft += self.ft_step * int((self._t0 - self._last_made) * self.rate_hz)
                self._made_in_stream = 0

    def _stream(self) -> None:
        with self._lock:
            if self._client is None:
                return
            due = int((time.monotonic() - self._t0) * self.rate_hz) + 1 - self._made_in_stream
            per = self.per_datagram if self._buffered else 1
            while due >= per:
                n = per if not self._limited else min(per, self._remaining)
                if n <= 0:
                    self._flush_held(late=False)
                    self._client = None
                    return
                self._emit(n)
                due -= n
                if self._limited:
                    self._remaining -= n

    def _emit(self, n: int) -> None:
        rows = (self._index + np.arange(n))
        rows = rows % len(self.wrench_S) if self.loop else np.minimum(rows, len(self.wrench_S) - 1)
        self._index += n
        t = (self._made_in_stream + np.arange(n)) / self.rate_hz
        spec = self.spec
        sigma = np.array([spec.noise[0]] * 3 + [spec.noise[1]] * 3)
        load = (self.wrench_S[rows] + np.asarray(spec.bias) + np.outer(t, spec.drift)
                + self._rng.normal(size=(n, 6)) * sigma)
        raw = np.clip(np.rint(load * self.scale), _INT32_MIN, _INT32_MAX).astype(np.int64)
        self._last_raw = raw[-1]
        counts = np.clip(raw - self._bias_counts, _INT32_MIN, _INT32_MAX)
        rdt = self._rdt + np.arange(n)
        if not self.freeze_ft:
            ft = self._ft + self.ft_step * (np.arange(n) + 1)
            self._ft = int(ft[-1])
        else:
            ft = np.full(n, self._ft)
        if self._glitch != (0, 0):
            rdt[0] += self._glitch[0]
            ft[0] += self._glitch[1]
            self._glitch = (0, 0)
        self._rdt += n
        self._last_made = self._t0 + (self._made_in_stream + n - 1) / self.rate_hz
        if self.emitted is not None:
            self.emitted.extend(zip(rows.tolist(), (self._t0_wall + t).tolist(), strict=True))
        self._made_in_stream += n
        self.stats.made += n
        data = pack_records(rdt, ft, np.full(n, self.status), counts)
        if self.mute or self._client is None:
            return
        draw = self._rng.random(2)
        if draw[0] < self.loss:
            self.stats.dropped += n
            return
        if self._held is None and draw[1] < self.reorder:
            self._held = data  # goes out after the next datagram
            self.stats.late += n
            return
        self._send(data)
        self._flush_held()

    def _flush_held(self, late: bool = True) -> None:
        """Send the held datagram: after a newer one (``late``), or in order at a stream's
        end (then it was not late after all)."""
        if self._held is not None:
            if not late:
                self.stats.late -= len(self._held) // 36
            if self._client is not None:
                self._send(self._held)
        self._held = None

    def _send(self, data: bytes) -> None:
        assert self._client is not None
        with contextlib.suppress(OSError):  # a client that went away: the device goes on
            self.sock.sendto(data, self._client)
