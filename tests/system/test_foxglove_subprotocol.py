"""Which WebSocket subprotocol the view takes (a real bridge process): ``foxglove.sdk.v1``, the
only one foxglove-sdk's server accepts; a client that offers only ``foxglove.websocket.v1`` (an
older Foxglove app) gets HTTP 400, and the bridge says so when it starts and when it refuses."""

from __future__ import annotations

import asyncio

import pytest

from tests.system.test_foxglove_keys import bridge_process
from vibrissa.nodes.foxglove_bridge import REFUSED_HINT, SUBPROTOCOL

pytest.importorskip("foxglove")
websockets = pytest.importorskip("websockets")


async def handshake(url: str, subprotocols: list[str]) -> str | int:
    """The subprotocol the server chose, or the HTTP status it refused the handshake with."""
    try:
        async with websockets.connect(url, subprotocols=subprotocols, open_timeout=30) as ws:
            return str(ws.subprotocol)
    except websockets.exceptions.InvalidStatus as exc:
        return int(exc.response.status_code)


def test_the_view_takes_foxglove_sdk_v1_and_refuses_foxglove_websocket_v1_alone() -> None:
    assert SUBPROTOCOL == "foxglove.sdk.v1" and "foxglove.websocket.v1" in REFUSED_HINT
    with bridge_process() as (url, seen):
        assert REFUSED_HINT in seen[-1]  # the address and, beside it, who cannot connect
        old = asyncio.run(handshake(url, ["foxglove.websocket.v1"]))
        both = asyncio.run(handshake(url, ["foxglove.websocket.v1", "foxglove.sdk.v1"]))
        new = asyncio.run(handshake(url, ["foxglove.sdk.v1"]))
        assert (old, both, new) == (400, "foxglove.sdk.v1", "foxglove.sdk.v1")
    refused = [line for line in seen if "refused 1 client(s) at the handshake (1 so far" in line]
    assert len(refused) == 1 and REFUSED_HINT in refused[0], "".join(seen)
