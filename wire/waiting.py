"""Waiting on an event for any number of seconds.

threading's waits refuse a timeout beyond ``threading.TIMEOUT_MAX`` (292 years on Linux) with
``OverflowError``: a bag whose log times jump by centuries, or a rate of 1e-300 Hz, asks for
one. `wait_event` waits in pieces instead, so that such a wait lasts as asked (until stopped).
"""

from __future__ import annotations

import threading
import time

__all__ = ["wait_event"]


def wait_event(event: threading.Event, seconds: float) -> bool:
    """``event.wait(seconds)`` for any ``seconds`` (inf: until set; not > 0: no wait); whether
    ``event`` is set."""
    if not seconds > 0:
        return event.is_set()
    deadline = time.monotonic() + seconds
    while not event.wait(min(deadline - time.monotonic(), threading.TIMEOUT_MAX)):
        if time.monotonic() >= deadline:
            return False
    return True
