"""A subscriber's receive queue, bounded in bytes, that adds no thread hop to a message.

The taker (the node's thread, in ``Subscriber.receive``) reads its sockets itself, one
message per ``take``, as a single-threaded subscriber would. While it is busy elsewhere, a drainer thread takes what
arrives off the sockets every ``DRAIN_PERIOD_S`` into a FIFO of at most ``max_bytes`` bytes.
Once the taker has waited in ``take`` for a whole period, the drainer sleeps until it leaves:
an idle node does not wake for it, and a busy one never wakes it (a thread's wake-up costs the
node CPU time and the GIL: woken at every message, the reconstructor's drainer woke 1 437 times
a second at 1 kHz ticks; on its own period, 502). So what a node buffers is that FIFO plus at most
``PIPE_HWM`` messages per connection in ZeroMQ (more push back on the sender), whatever
ZeroMQ's marks in messages would allow. One lock serialises every use of the sockets, which is
what ZeroMQ asks of a socket shared by threads.

Beyond the bound the arriving message is dropped and counted here; its sequence number is
then missing downstream, so the subscriber counts it as lost like any other gap. A payload
longer than ``payload_limit(topic frame)`` is not kept: its message is queued with an empty
payload and the length it had, for the taker to refuse and count.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import zmq

__all__ = ["DRAIN_PERIOD_S", "PIPE_HWM", "Inbox"]

log = logging.getLogger(__name__)

PIPE_HWM = 1000
"""Receive high-water mark of an inbox's sockets, messages per connection: what ZeroMQ holds
while the drainer sleeps (more push back on the sender)."""

DRAIN_PERIOD_S = 0.005
"""How often the drainer takes up to ``_FAIR_RUN`` messages off each socket while the taker is
busy elsewhere (beyond that rate ZeroMQ holds the rest, then pushes back): ``PIPE_HWM`` per
connection lasts 15 ms at 64 000 messages/s."""

_FAIR_RUN = 64  # messages in a row from one socket before the others get a turn


class Inbox:
    """Messages (``[topic, header, payload]`` frames) from ``sockets``, oldest first, through a
    FIFO of at most ``max_bytes`` bytes and ``max_messages`` messages (``dropped``,
    ``dropped_bytes``: what did not fit; one warning per run of drops)."""

    def __init__(self, sockets: list[zmq.Socket[Any]], max_bytes: int, max_messages: int,
                 payload_limit: Callable[[bytes], int], name: str = "vibrissa-inbox") -> None:
        if max_bytes < 1 or max_messages < 1:
            raise ValueError(f"an inbox needs room: max_bytes {max_bytes}, "
                             f"max_messages {max_messages}")
        self.max_bytes = max_bytes
        self.max_messages = max_messages
        self.dropped = 0
        self.dropped_bytes = 0
        self._payload_limit = payload_limit
        self._sockets = list(sockets)
        self._poller = zmq.Poller()
        for sock in self._sockets:
            self._poller.register(sock, zmq.POLLIN)
        self._queue: deque[tuple[list[bytes], int, int]] = deque()  # frames, size, cut
        self._bytes = 0
        self._dropping = False
        self._turn = 0  # the socket read first next time
        self._lock = threading.Lock()  # the sockets, the FIFO and its counts
        self._stop = threading.Event()
        self._taking_since: float | None = None  # when the taker entered take (None: not in it)
        self._drainer_asleep = False  # until the taker leaves take, on _wake
        self._wake = threading.Event()
        self._thread = threading.Thread(target=self._drain_while_busy, name=name, daemon=True)
        self._thread.start()

    @property
    def queued_bytes(self) -> int:
        """Bytes taken off the sockets and not yet by the taker."""
        return self._bytes

    def take(self, timeout_s: float) -> tuple[list[bytes], int] | None:
        """The oldest message and, when its payload was cut for its length, that length
        (else 0); ``None`` when none arrives within ``timeout_s`` seconds."""
        self._taking_since = now = time.monotonic()
        deadline = now + timeout_s
        try:
            with self._lock:
                while True:
                    if self._queue:
                        frames, size, cut = self._queue.popleft()
                        self._bytes -= size
                        return frames, cut
                    remaining_ms = round((deadline - time.monotonic()) * 1000)
                    if remaining_ms < 0 or self._stop.is_set():
                        return None
                    ready = self._ready(max(0, remaining_ms))
                    if not ready:
                        return None
                    taken = self._read_one(ready)
                    if taken is not None:
                        return taken
        finally:
            self._taking_since = None
            if self._drainer_asleep:  # read after the line above: the drainer cannot miss it
                self._wake.set()

    def run_locked(self, command: Callable[[], None]) -> None:
        """Run ``command`` with the sockets to itself (any thread)."""
        with self._lock:
            command()

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop the drainer and close every socket (idempotent)."""
        self._stop.set()
        self._wake.set()  # a drainer asleep until the taker leaves take wakes to its end
        self._thread.join(timeout_s)
        with self._lock:
            for sock in self._sockets:
                sock.close()

    def _drain_while_busy(self) -> None:
        """One pass over the sockets per period while the taker is busy elsewhere (never a loop
        that a flood could keep going while the taker waits for the lock); none while it
        waits in ``take``, where it reads them itself, and asleep once it has waited there a
        whole period, until it leaves."""
        while not self._stop.wait(DRAIN_PERIOD_S):
            since = self._taking_since
            if since is not None:
                if time.monotonic() - since >= DRAIN_PERIOD_S:
                    self._wake.clear()
                    self._drainer_asleep = True
                    if self._taking_since is not None:  # checked after the flag is up
                        self._wake.wait()
                    self._drainer_asleep = False
                continue
            if self._lock.acquire(blocking=False):
                try:
                    self._read()
                except zmq.ZMQError:
                    # a context destroyed under it closes its sockets: that is an end
                    if not any(sock.closed for sock in self._sockets):
                        raise
                    return
                finally:
                    self._lock.release()

    def _ready(self, timeout_ms: int) -> set[zmq.Socket[Any]]:
        """The sockets readable within ``timeout_ms``: one poll finds them (a read of a socket
        with nothing on it raises, which costs more). Holds the lock."""
        return {sock for sock, _ in self._poller.poll(timeout_ms)}

    def _read_one(self, ready: set[zmq.Socket[Any]]) -> tuple[list[bytes], int] | None:
        """The next message of the ``ready`` sockets, the first in turn, as ``take`` returns
        it; ``None`` when none had one after all. The taker reads one at a time and queues
        nothing: no FIFO round trip, and no read that finds a socket empty and raises
        (ZeroMQ's ``Again``). Holds the lock."""
        n = len(self._sockets)
        for k in range(n):
            sock = self._sockets[(self._turn + k) % n]
            if sock in ready:
                try:
                    frames = sock.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    continue
                self._turn = (self._turn + k + 1) % n
                return frames, self._cut(frames)
        return None

    def _read(self, timeout_ms: int = 0) -> bool:
        """Queue (or drop) what is on the sockets that are readable within ``timeout_ms``, at
        most ``_FAIR_RUN`` from each, starting with the next socket in turn; whether any was.
        Holds the lock."""
        ready = self._ready(timeout_ms)
        if not ready:
            return False
        n = len(self._sockets)
        for k in range(n):
            sock = self._sockets[(self._turn + k) % n]
            if sock not in ready:
                continue
            for _ in range(_FAIR_RUN):
                try:
                    frames = sock.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                self._put(frames)
        self._turn = (self._turn + 1) % n
        return True

    def _cut(self, frames: list[bytes]) -> int:
        """The length of a payload too long to keep (emptied in ``frames``), else 0."""
        if len(frames) == 3 and len(frames[2]) > self._payload_limit(frames[0]):
            cut = len(frames[2])
            frames[2] = b""  # let go of it before the next one arrives
            return cut
        return 0

    def _put(self, frames: list[bytes]) -> None:
        cut = self._cut(frames)
        size = sum(len(frame) for frame in frames)
        if not self._queue or (self._bytes + size <= self.max_bytes
                               and len(self._queue) < self.max_messages):
            self._queue.append((frames, size, cut))
            self._bytes += size
            self._dropping = False
            return
        self.dropped += 1
        self.dropped_bytes += size
        if not self._dropping:
            log.warning("receive queue full (%d messages, %d of %d bytes): dropping what "
                        "arrives until it drains", len(self._queue), self._bytes,
                        self.max_bytes)
        self._dropping = True
