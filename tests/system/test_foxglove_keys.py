"""A keyed graph does not leak through its viewer: the Foxglove bridge (whose clients are not
authenticated) refuses to serve a graph with keys unless told to; refused WebSocket clients
are counted and logged a line per interval, not a line each (real processes)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from vibrissa.wire.security import create_keys
from vibrissa.wire.transport import Endpoints, Proxy

pytest.importorskip("foxglove")
websockets = pytest.importorskip("websockets")

DEADLINE_S = 180.0  # generous: a node starts in seconds idle, tens of seconds at load 20


def test_a_keyed_graph_is_not_served_to_unauthenticated_viewers(tmp_path: Path) -> None:
    create_keys(tmp_path / "keys")
    done = subprocess.run([sys.executable, "-m", "vibrissa.cli.launch", "view", "--keys",
                           str(tmp_path / "keys"), f"out:={tmp_path / 'out'}", "port:=0"],
                          capture_output=True, text=True, timeout=DEADLINE_S, check=False)
    assert done.returncode != 0, done.stderr
    assert "parameter" not in done.stderr or "allow_unauthenticated_view" in done.stderr
    assert ("the graph has keys, but Foxglove clients are not authenticated" in done.stderr
            and "allow_unauthenticated_view:=true" in done.stderr), done.stderr
    assert "serving the graph to Foxglove" not in done.stderr


@contextlib.contextmanager
def bridge_process(endpoints: Endpoints | None = None) -> Iterator[tuple[str, list[str]]]:
    """A real bridge process on the graph of ``endpoints`` (default: a graph of its own): (its
    ws:// address, its stderr lines so far). Leaving stops it with SIGINT and collects every
    line it wrote."""
    with contextlib.ExitStack() as stack:
        if endpoints is None:
            endpoints = stack.enter_context(Proxy(Endpoints.free())).endpoints
        assert endpoints is not None
        env = {**os.environ, **endpoints.to_env()}
        bridge = subprocess.Popen([sys.executable, "-m", "vibrissa.nodes.foxglove_bridge",
                                   "--name", "foxglove_bridge", "--param", "port:=0"],
                                  env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                  text=True)
        lines: queue.Queue[str | None] = queue.Queue()

        def read() -> None:
            assert bridge.stderr is not None
            for line in bridge.stderr:
                lines.put(line)
            lines.put(None)

        threading.Thread(target=read, daemon=True).start()
        seen: list[str] = []
        try:
            deadline = time.monotonic() + DEADLINE_S
            url = None
            while url is None:
                line = lines.get(timeout=max(0.1, deadline - time.monotonic()))
                assert line is not None, "".join(seen)
                seen.append(line)
                found = re.search(r"serving the graph to Foxglove on (ws://[^\s;)]+)", line)
                url = found.group(1) if found else None
            yield url, seen
            bridge.send_signal(signal.SIGINT)
            bridge.wait(timeout=DEADLINE_S)
        finally:
            if bridge.poll() is None:
                bridge.kill()
        while (line := lines.get(timeout=30)) is not None:
            seen.append(line)


def test_refused_clients_are_counted_and_logged_once_per_interval() -> None:
    with bridge_process() as (url, seen):

        async def knock(n: int) -> int:
            refused = 0
            for _ in range(n):
                try:
                    async with websockets.connect(url, subprotocols=["bogus"], open_timeout=30):
                        pass
                except websockets.exceptions.InvalidStatus:
                    refused += 1
            return refused

        assert asyncio.run(knock(200)) == 200
    err = "".join(seen)
    assert "refused 200 client(s) at the handshake" in err, err
    knocks = [line for line in seen if "handshake" in line]
    assert 2 <= len(knocks) <= 4, knocks  # the first, maybe one per 10 s, and the closing line
