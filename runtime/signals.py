"""SIGINT/SIGTERM handling: the one place that installs and restores handlers.

A handler only records (calls ``on_signal(signum)``): whoever installed it acts in its own loop,
since a handler runs between any two bytecodes and must not take locks. Handlers can only be
installed from the main thread; elsewhere installing is a no-op.

An orphan ends whatever it is doing: a SIGTERM that comes when the parent is gone (the
launcher's death signal, ``PR_SET_PDEATHSIG``, after a SIGKILL of the launcher) also arms an
alarm whose default action ends the process `ORPHAN_GRACE_S` later, if its own loop has not
ended it by then (a node busy computing a long sweep does not look at its stop flag). The
kernel delivers the alarm, so no lock is taken and no Python code must run.
"""

from __future__ import annotations

import os
import signal
import threading
import types
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
ORPHAN_GRACE_S = 5
"""Seconds an orphaned process has, after its SIGTERM, to end by itself (a recorder closes its
bag in well under one)."""


class SignalHandlers:
    """Calls ``on_signal(signum)`` on ``signums`` between :meth:`install` and :meth:`restore`
    (or inside a ``with`` block), then puts the previous handlers back. With ``once``, a signal
    takes its default action after its first time: the same signal again ends the process at
    once, even in a native call that holds the interpreter (another of ``signums`` calls
    ``on_signal`` again: the launcher's SIGTERM after its grace for a SIGINT)."""

    def __init__(self, on_signal: Callable[[int], None],
                 signums: Sequence[signal.Signals] = STOP_SIGNALS, once: bool = False) -> None:
        self._on_signal = on_signal
        self._signums = tuple(signums)
        self._once = once
        self._previous: dict[int, Any] = {}  # what signal.signal returned
        self._parent = os.getppid()

    def install(self) -> None:
        """Install the handlers (main thread only; a no-op elsewhere)."""
        if threading.current_thread() is threading.main_thread() and not self._previous:
            self._previous = {s: signal.signal(s, self._handle) for s in self._signums}

    def restore(self) -> None:
        """Put the previous handlers back (idempotent)."""
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()

    def _handle(self, signum: int, frame: types.FrameType | None) -> None:
        if signum == signal.SIGTERM and os.getppid() != self._parent:  # orphaned
            signal.signal(signal.SIGALRM, signal.SIG_DFL)
            signal.alarm(ORPHAN_GRACE_S)
        if self._once:
            signal.signal(signum, signal.SIG_DFL)
        self._on_signal(signum)

    def __enter__(self) -> SignalHandlers:
        self.install()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.restore()


@contextmanager
def default_actions(signums: Sequence[signal.Signals] = STOP_SIGNALS) -> Iterator[None]:
    """While inside, ``signums`` take their default action: SIGINT and SIGTERM end the process
    at once. For a native call that holds the interpreter for seconds (no Python handler runs
    until it returns). Main thread only; elsewhere a no-op."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, signal.SIG_DFL) for s in signums}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
