"""A subscriber's receive queue, bounded in bytes: a thread takes every message off its
sockets as it arrives, so what a node buffers is what this queue holds, whatever ZeroMQ's
high-water marks (counted in messages) would allow.

Beyond the bound the arriving message is dropped and counted here; its sequence number is
then missing downstream, so the subscriber counts it as lost like any other gap.
"""

from __future__ import annotations

import itertools
import logging
import os
import queue
import threading
from collections import deque
from collections.abc import Callable
from typing import Any

import zmq

__all__ = ["PIPE_HWM", "Inbox"]

log = logging.getLogger(__name__)

PIPE_HWM = 16
"""Receive high-water mark of an inbox's sockets, messages: the thread empties them as they
fill, so ZeroMQ holds at most this many per connection (more push back on the sender)."""

_FAIR_RUN = 64  # messages in a row from one socket before the others get a turn
_WAKE_IDS = itertools.count()


class Inbox:
    """Takes messages (``[topic, header, payload]`` frames) off ``sockets`` on a thread of its
    own, into a FIFO of at most ``max_bytes`` bytes and ``max_messages`` messages.

    The thread owns the sockets from here on: other threads reach them only through
    ``call``. A message that does not fit is dropped and counted (``dropped``,
    ``dropped_bytes``), with one warning per run of drops. A payload longer than
    ``payload_limit(topic frame)`` is not kept: its message is queued with an empty payload
    and the length it had, for the taker to refuse and count.
    """

    def __init__(self, context: zmq.Context[Any], sockets: list[zmq.Socket[Any]],
                 max_bytes: int, max_messages: int, payload_limit: Callable[[bytes], int],
                 name: str = "vibrissa-inbox") -> None:
        if max_bytes < 1 or max_messages < 1:
            raise ValueError(f"an inbox needs room: max_bytes {max_bytes}, "
                             f"max_messages {max_messages}")
        self.max_bytes = max_bytes
        self.max_messages = max_messages
        self.dropped = 0
        self.dropped_bytes = 0
        self._payload_limit = payload_limit
        self._sockets = list(sockets)
        self._queue: deque[tuple[list[bytes], int, int]] = deque()  # frames, size, cut
        self._bytes = 0
        self._dropping = False
        self._ready = threading.Condition(threading.Lock())
        self._closed = False
        self._commands: queue.SimpleQueue[Callable[[], None] | None] = queue.SimpleQueue()
        address = f"inproc://{name}-{os.getpid()}-{next(_WAKE_IDS)}"
        self._wake_in = context.socket(zmq.PAIR)
        self._wake_in.setsockopt(zmq.LINGER, 0)
        self._wake_in.bind(address)
        self._wake_out = context.socket(zmq.PAIR)
        self._wake_out.setsockopt(zmq.LINGER, 0)
        self._wake_out.connect(address)
        self._wake_lock = threading.Lock()
        self._poller = zmq.Poller()
        for sock in (self._wake_in, *self._sockets):
            self._poller.register(sock, zmq.POLLIN)
        # Thread start is the memory barrier ZeroMQ asks for when sockets change threads.
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    @property
    def queued_bytes(self) -> int:
        """Bytes waiting to be taken."""
        return self._bytes

    def take(self, timeout_s: float) -> tuple[list[bytes], int] | None:
        """The oldest message and, when its payload was cut for its length, that length
        (else 0); ``None`` when none arrives within ``timeout_s`` seconds."""
        with self._ready:
            if not self._queue:
                self._ready.wait_for(lambda: self._queue or self._closed, max(0.0, timeout_s))
            if not self._queue:
                return None
            frames, size, cut = self._queue.popleft()
            self._bytes -= size
            return frames, cut

    def call(self, command: Callable[[], None]) -> None:
        """Run ``command`` on the inbox thread (the only one that may touch its sockets)."""
        self._commands.put(command)
        self._wake()

    def add_socket(self, sock: zmq.Socket[Any]) -> None:
        """Take messages from ``sock`` too; call on the inbox thread (from a ``call``)."""
        self._sockets.append(sock)
        self._poller.register(sock, zmq.POLLIN)

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop the thread and close every socket (idempotent)."""
        if self._thread.is_alive():
            self._commands.put(None)
            self._wake()
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                log.error("%s did not stop within %.1f s", self._thread.name, timeout_s)
        with self._wake_lock:
            self._wake_out.close()
        with self._ready:
            self._closed = True
            self._ready.notify_all()

    def _wake(self) -> None:
        with self._wake_lock:
            if not self._wake_out.closed:
                self._wake_out.send(b"", zmq.NOBLOCK)

    def _run(self) -> None:
        try:
            while self._serve():
                pass
        except zmq.ContextTerminated:
            pass
        except zmq.ZMQError as exc:
            # a context destroyed under it closes its sockets: that is an end, not a fault
            if not any(sock.closed for sock in (self._wake_in, *self._sockets)):
                log.error("%s stopped: %s", self._thread.name, exc)
        finally:
            for sock in (self._wake_in, *self._sockets):
                sock.close()
            with self._ready:
                self._closed = True
                self._ready.notify_all()

    def _serve(self) -> bool:
        """One round: run the commands, then take what is queued on each ready socket, at
        most ``_FAIR_RUN`` messages each so that no socket starves the others."""
        ready = dict(self._poller.poll())
        if self._wake_in in ready:
            while True:
                try:
                    self._wake_in.recv(zmq.NOBLOCK)
                except zmq.Again:
                    break
            while True:
                try:
                    command = self._commands.get_nowait()
                except queue.Empty:
                    break
                if command is None:
                    return False
                command()
        batch: list[tuple[list[bytes], int]] = []
        for sock in self._sockets:
            if sock not in ready:
                continue
            for _ in range(_FAIR_RUN):
                try:
                    frames = sock.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                cut = 0
                if len(frames) == 3 and len(frames[2]) > self._payload_limit(frames[0]):
                    cut = len(frames[2])
                    frames[2] = b""  # let go of it before the next one arrives
                batch.append((frames, cut))
        if batch:
            self._put(batch)
        return True

    def _put(self, batch: list[tuple[list[bytes], int]]) -> None:
        """Queue what fits of ``batch`` (one lock for all), drop and count the rest."""
        starts = False
        with self._ready:
            was_empty = not self._queue
            for frames, cut in batch:
                size = sum(len(frame) for frame in frames)
                if not self._queue or (self._bytes + size <= self.max_bytes
                                       and len(self._queue) < self.max_messages):
                    self._queue.append((frames, size, cut))
                    self._bytes += size
                    self._dropping = False
                    continue
                self.dropped += 1
                self.dropped_bytes += size
                starts = starts or not self._dropping
                self._dropping = True
            if was_empty and self._queue:
                self._ready.notify()  # only an empty queue has a taker waiting
            queued, queued_bytes = len(self._queue), self._bytes
        if starts:
            log.warning("receive queue full (%d messages, %d of %d bytes): dropping what "
                        "arrives until it drains", queued, queued_bytes, self.max_bytes)
