"""Which WebSocket subprotocol the view takes (a real bridge process): ``foxglove.sdk.v1``, the
only one foxglove-sdk's server accepts; a client that offers only ``foxglove.websocket.v1`` (an
older Foxglove app) gets HTTP 400, and the bridge says so when it starts and when it refuses."""

from __future__ import annotations

import asyncio
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time

import pytest

from vibrissa.nodes.foxglove_bridge import REFUSED_HINT, SUBPROTOCOL
from vibrissa.wire.transport import Endpoints, Proxy

pytest.importorskip("foxglove")
websockets = pytest.importorskip("websockets")

DEADLINE_S = 180.0  # generous: a node starts in seconds idle, tens of seconds at load 20


async def handshake(url: str, subprotocols: list[str]) -> str | int:
    """The subprotocol the server chose, or the HTTP status it refused the handshake with."""
    try:
        async with websockets.connect(url, subprotocols=subprotocols, open_timeout=30) as ws:
            return str(ws.subprotocol)
    except websockets.exceptions.InvalidStatus as exc:
        return int(exc.response.status_code)


def test_the_view_takes_foxglove_sdk_v1_and_refuses_foxglove_websocket_v1_alone() -> None:
    assert SUBPROTOCOL == "foxglove.sdk.v1" and "foxglove.websocket.v1" in REFUSED_HINT
    with Proxy(Endpoints.free()) as proxy:
        assert proxy.endpoints is not None
        env = {**os.environ, **proxy.endpoints.to_env()}
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
            assert REFUSED_HINT in seen[-1]  # the address and, beside it, who cannot connect
            old = asyncio.run(handshake(url, ["foxglove.websocket.v1"]))
            both = asyncio.run(handshake(url, ["foxglove.websocket.v1", "foxglove.sdk.v1"]))
            new = asyncio.run(handshake(url, ["foxglove.sdk.v1"]))
            assert (old, both, new) == (400, "foxglove.sdk.v1", "foxglove.sdk.v1")
            bridge.send_signal(signal.SIGINT)
            bridge.wait(timeout=DEADLINE_S)
        finally:
            if bridge.poll() is None:
                bridge.kill()
        while (line := lines.get(timeout=30)) is not None:
            seen.append(line)
    refused = [line for line in seen if "refused 1 client(s) at the handshake (1 so far" in line]
    assert len(refused) == 1 and REFUSED_HINT in refused[0], "".join(seen)
