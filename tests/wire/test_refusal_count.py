"""The guard counts each connection that ended without an authenticated handshake exactly
once, whatever it was: a bare TCP connection that leaves at once, a plain-text ZeroMQ peer, a
peer with a key not allowed; never an admitted peer. And it logs them a line per interval,
not a line each."""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zmq

from vibrissa.wire.security import Guard, Keys, create_keys

DEADLINE_S = 120.0


@pytest.fixture
def server(tmp_path: Path) -> Iterator[tuple[zmq.Context[Any], str, Path]]:
    """A CURVE server socket of a graph's keys, bound on loopback; its context and address."""
    create_keys(tmp_path / "keys", ("laptop",))
    create_keys(tmp_path / "other", ("mallory",))
    context: zmq.Context[Any] = zmq.Context()
    pub = context.socket(zmq.PUB)
    pub.setsockopt(zmq.LINGER, 0)
    Keys.load(tmp_path / "keys").serve_with(pub, context)
    port = pub.bind_to_random_port("tcp://127.0.0.1")
    try:
        yield context, f"tcp://127.0.0.1:{port}", tmp_path
    finally:
        Guard.stop_for(context)
        pub.close(linger=0)
        context.destroy(linger=0)


def wait_refused(context: zmq.Context[Any], n: int) -> int:
    deadline = time.monotonic() + DEADLINE_S
    while Guard.refused_in(context) < n and time.monotonic() < deadline:
        time.sleep(0.05)
    return Guard.refused_in(context)


def test_every_refused_connection_is_counted_once(
        server: tuple[zmq.Context[Any], str, Path], caplog: pytest.LogCaptureFixture) -> None:
    context, address, folder = server
    host, port = address.removeprefix("tcp://").split(":")
    clients: zmq.Context[Any] = zmq.Context()
    try:
        admitted = clients.socket(zmq.SUB)
        Keys.load(folder / "keys" / "clients" / "laptop").connect_with(admitted)
        admitted.connect(address)
        with caplog.at_level(logging.WARNING, logger="vibrissa.wire.security"):
            for _ in range(300):  # connect and leave before any greeting
                socket.create_connection((host, int(port)), timeout=10).close()
            assert wait_refused(context, 300) == 300
            for _ in range(20):  # plain-text ZeroMQ peers, one attempt each
                plain = clients.socket(zmq.SUB)
                plain.setsockopt(zmq.RECONNECT_IVL, 10_000)
                plain.connect(address)
                time.sleep(0.05)
                plain.close(linger=0)
            intruder = clients.socket(zmq.SUB)  # a key the graph does not allow
            mallory = Keys.load(folder / "other" / "clients" / "mallory")
            intruder.curve_secretkey, intruder.curve_publickey = mallory.secret, mallory.public
            intruder.curve_serverkey = Keys.load(folder / "keys").public
            intruder.setsockopt(zmq.RECONNECT_IVL, 10_000)  # one attempt in the test's time
            intruder.connect(address)
            assert wait_refused(context, 320) >= 320
            intruder.close(linger=0)
            assert wait_refused(context, 321) == 321
        admitted.close(linger=0)  # an admitted peer that leaves is no refusal
        time.sleep(0.5)
        assert Guard.refused_in(context) == 321
        lines = [r for r in caplog.records if "refused" in r.getMessage()]
        assert 1 <= len(lines) <= 3, [r.getMessage() for r in lines]
    finally:
        clients.destroy(linger=0)
