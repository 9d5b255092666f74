"""CURVE: key folders, and that a peer without an allowed key neither injects nor reads.

Members, clients and intruders each have a ZeroMQ context of their own, as separate processes
would (a context's ZAP handler serves only its own sockets).
"""

from __future__ import annotations

import logging
import os
import stat
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zmq
import zmq.auth

from vibrissa.msgs import NodeStatus, WhiskerWrenchArray
from vibrissa.wire import STATUS_TOPIC, Endpoints, Proxy, Publisher, Subscriber
from vibrissa.wire.security import Guard, Keys, KeysError, create_keys

TOPIC = "/w0/wrench"
LISTEN_S = 1.0


def wrench(seq: int) -> WhiskerWrenchArray:
    return WhiskerWrenchArray(
        stamp=0.001 * seq, seq=seq, whisker_ids=["w0"], frame_ids=["w0/clamp"],
        pose_frame_id="world", clamp_position=[[0.0, 0.0, 0.1]], clamp_orientation=[[0.0, 0.0, 0.0, 1.0]],
        f0=[[0.0, 0.01, 0.0]], m0=[[0.0, 0.0, 0.0]],
    )


@pytest.fixture
def keys_dir(tmp_path: Path) -> Path:
    folder = tmp_path / "keys"
    create_keys(folder, ("laptop",))
    return folder


@pytest.fixture
def contexts() -> Iterator[list[zmq.Context[Any]]]:
    """Fresh contexts on demand (``contexts.append``-free: index them), destroyed after."""
    made: list[zmq.Context[Any]] = [zmq.Context() for _ in range(4)]
    yield made
    for ctx in made:
        Guard.stop_for(ctx)
        ctx.destroy(linger=0)


@pytest.fixture
def secured(keys_dir: Path, contexts: list[zmq.Context[Any]]) -> Iterator[Proxy]:
    """A proxy of the graph of ``keys_dir`` on free loopback ports, in context 0."""
    free = Endpoints.free().with_keys(Keys.load(keys_dir))
    with Proxy(free, context=contexts[0]) as proxy:
        yield proxy


def stranger_keys(tmp_path: Path, server_public: bytes) -> Keys:
    """A well-formed CURVE identity the graph never allowed, aimed at the graph's real
    (public) server key: what an intruder who read graph.key can build."""
    public, secret = zmq.curve_keypair()
    return Keys(tmp_path, "stranger", public, secret, server_public, frozenset())


def heard(sub: Subscriber, timeout_s: float) -> list[WhiskerWrenchArray]:
    got = []
    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        rx = sub.receive(left)
        if rx is not None and isinstance(rx.msg, WhiskerWrenchArray):
            got.append(rx.msg)
    return got


def publish_while(pub: Publisher, sub: Subscriber, timeout_s: float) -> list[WhiskerWrenchArray]:
    """Publish a wrench every 10 ms for ``timeout_s`` while listening with ``sub``."""
    got = []
    deadline = time.monotonic() + timeout_s
    seq = 0
    while time.monotonic() < deadline:
        pub.publish(wrench(seq))
        seq += 1
        got += heard(sub, 0.01)
    return got


# -- key folders --------------------------------------------------------------------------------

def test_key_folder_layout_and_modes(tmp_path: Path) -> None:
    folder = tmp_path / "keys"
    written = create_keys(folder, ("laptop",))
    assert {p.relative_to(folder).as_posix() for p in written} == {
        "graph.key", "graph.key_secret", "clients/laptop/laptop.key",
        "clients/laptop/laptop.key_secret", "clients/laptop/graph.key", "authorized/laptop.key"}
    for secret in (folder / "graph.key_secret", folder / "clients/laptop/laptop.key_secret"):
        assert stat.S_IMODE(secret.stat().st_mode) == 0o600
    for private in (folder, folder / "clients", folder / "clients/laptop", folder / "authorized"):
        assert stat.S_IMODE(private.stat().st_mode) == 0o700
    assert create_keys(folder, ("laptop",)) == []  # nothing is overwritten

    graph, laptop = Keys.load(folder), Keys.load(folder / "clients/laptop")
    assert graph.serves and not laptop.serves
    assert laptop.server_public == graph.public == graph.server_public
    assert laptop.public in graph.allowed and graph.public in graph.allowed
    assert zmq.auth.load_certificate(folder / "authorized/laptop.key")[0] == laptop.public
    for keys in (graph, laptop):  # a secret never shows in a log line or a traceback
        assert keys.secret.decode() not in repr(keys)
        assert keys.secret.decode() not in repr(Endpoints.for_domain(0).with_keys(keys))


def test_unusable_key_folders_are_refused_by_name(tmp_path: Path, keys_dir: Path) -> None:
    with pytest.raises(KeysError, match="does not exist"):
        Keys.load(tmp_path / "nowhere")
    os.chmod(keys_dir / "graph.key_secret", 0o644)
    with pytest.raises(KeysError, match=r"graph.key_secret is accessible by others .*0644"):
        Keys.load(keys_dir)
    os.chmod(keys_dir / "graph.key_secret", 0o600)
    os.chmod(keys_dir / "authorized", 0o777)
    with pytest.raises(KeysError, match="authorized may be written by others"):
        Keys.load(keys_dir)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(KeysError, match="found none"):
        Keys.load(empty)
    with pytest.raises(KeysError, match="client name"):
        create_keys(keys_dir, ("../up",))


def test_a_client_cannot_bind_for_the_graph(keys_dir: Path,
                                            contexts: list[zmq.Context[Any]]) -> None:
    laptop = Keys.load(keys_dir / "clients/laptop")
    with pytest.raises(KeysError, match="cannot bind"):
        Proxy(Endpoints.free().with_keys(laptop), context=contexts[1]).start()


# -- nobody unauthenticated gets in -------------------------------------------------------------

def test_members_and_allowed_clients_talk_intruders_read_nothing(
    secured: Proxy, keys_dir: Path, tmp_path: Path, contexts: list[zmq.Context[Any]]
) -> None:
    assert secured.endpoints is not None
    member = secured.endpoints
    laptop = member.with_keys(Keys.load(keys_dir / "clients/laptop"))
    plain = member.with_keys(None)
    stranger = member.with_keys(stranger_keys(tmp_path, member.keys.public))  # type: ignore[union-attr]
    readers = {
        "laptop": Subscriber({TOPIC: WhiskerWrenchArray}, laptop, contexts[1]),
        "plain": Subscriber({TOPIC: WhiskerWrenchArray}, plain, contexts[2]),
        "stranger": Subscriber({TOPIC: WhiskerWrenchArray}, stranger, contexts[3]),
    }
    with Publisher(TOPIC, WhiskerWrenchArray, member, contexts[0]) as pub:
        got = {name: [] for name in readers}  # type: dict[str, list[WhiskerWrenchArray]]
        deadline = time.monotonic() + 2 * LISTEN_S
        seq = 0
        while time.monotonic() < deadline:
            pub.publish(wrench(seq))
            seq += 1
            for name, sub in readers.items():
                got[name] += heard(sub, 0.003)
    for sub in readers.values():
        sub.close()
    assert len(got["laptop"]) > 50, "an allowed client must read the graph"
    assert got["plain"] == [] and got["stranger"] == []
    assert secured.refused >= 2  # both intruders, each counted (they retry: at least once)


def test_intruders_inject_nothing_and_are_counted(
    secured: Proxy, tmp_path: Path, contexts: list[zmq.Context[Any]],
    caplog: pytest.LogCaptureFixture,
) -> None:
    assert secured.endpoints is not None
    member = secured.endpoints
    stranger = member.with_keys(stranger_keys(tmp_path, member.keys.public))  # type: ignore[union-attr]
    with (caplog.at_level(logging.WARNING, "vibrissa.wire.security"),
          Subscriber({TOPIC: WhiskerWrenchArray, STATUS_TOPIC: NodeStatus}, member, contexts[0]) as sub,
          Publisher(TOPIC, WhiskerWrenchArray, member.with_keys(None), contexts[1]) as plain,
          Publisher(TOPIC, WhiskerWrenchArray, stranger, contexts[2]) as forged,
          Publisher(TOPIC, WhiskerWrenchArray, member, contexts[3]) as own):
        for pub in (plain, forged):
            assert publish_while(pub, sub, LISTEN_S) == []
        assert len(publish_while(own, sub, 0.3)) > 5  # the subscriber was listening
    assert sub.counters[TOPIC].rejected == 0 and sub.counters[TOPIC].lost == 0
    assert secured.refused >= 2
    assert "without an allowed key" in caplog.text


def test_direct_publishers_serve_with_the_graph_key(
    secured: Proxy, tmp_path: Path, contexts: list[zmq.Context[Any]]
) -> None:
    """A member's direct endpoint is a CURVE server too: a plain or stranger subscriber that
    connects to it straight (bypassing the proxy) reads nothing; a member reads."""
    assert secured.endpoints is not None
    member = secured.endpoints
    with Publisher(TOPIC, WhiskerWrenchArray, member, contexts[1], direct=True) as pub:
        assert pub.endpoint is not None
        got = {}
        for name, keys, ctx in (("member", member.keys, contexts[0]),
                                ("plain", None, contexts[2]),
                                ("stranger", stranger_keys(tmp_path, member.keys.public),  # type: ignore[union-attr]
                                 contexts[3])):
            sock = ctx.socket(zmq.SUB)
            sock.setsockopt(zmq.LINGER, 0)
            if keys is not None:
                keys.connect_with(sock)
            sock.setsockopt(zmq.SUBSCRIBE, b"")
            sock.connect(pub.endpoint)
            frames = 0
            deadline = time.monotonic() + LISTEN_S
            while time.monotonic() < deadline:
                pub.publish(wrench(0))
                if sock.poll(10):
                    sock.recv_multipart()
                    frames += 1
            sock.close()
            got[name] = frames
    assert got["member"] > 10 and got["plain"] == 0 and got["stranger"] == 0
    assert Guard.refused_in(contexts[1]) >= 2


def test_a_forged_announcement_cannot_send_subscribers_elsewhere(
    endpoints: Endpoints, context: zmq.Context[Any], caplog: pytest.LogCaptureFixture
) -> None:
    """Without keys anyone on the machine may publish a status: a subscriber still connects
    only to endpoints beside the proxy, never to another host."""
    elsewhere = "tcp://192.0.2.1:5555"
    with (caplog.at_level(logging.WARNING, "vibrissa.wire.transport"),
          Subscriber({TOPIC: WhiskerWrenchArray}, endpoints, context) as sub,
          Publisher(STATUS_TOPIC, NodeStatus, endpoints, context) as status):
        deadline = time.monotonic() + 2.0
        while elsewhere not in caplog.text and time.monotonic() < deadline:
            status.publish(NodeStatus(stamp=0.0, node="/forger", state="running", counters={},
                                      publishes={TOPIC: "vibrissa/WhiskerWrenchArray"},
                                      subscribes={}, seen_topics=[],
                                      endpoints={TOPIC: elsewhere}))
            sub.receive(0.05)
        assert sub.direct_endpoints == set()
    assert f"announces {elsewhere}" in caplog.text


@pytest.mark.parametrize(("announced", "allowed"), [
    ("tcp://127.0.0.1:41234", True),
    ("tcp://127.0.0.2:41234", False),
    ("tcp://127.0.0.1:41234/x", False),
    ("ipc:///tmp/other", False),
])
def test_direct_endpoints_allowed_only_beside_the_proxy(announced: str, allowed: bool) -> None:
    assert Endpoints.for_domain(3).allows_direct(announced) is allowed


def test_ipc_sockets_only_in_a_private_folder(tmp_path: Path,
                                              context: zmq.Context[Any]) -> None:
    shared = tmp_path / "shared"
    shared.mkdir(mode=0o755)
    os.chmod(shared, 0o755)
    with pytest.raises(zmq.ZMQError, match="must be yours and private"):
        Proxy(Endpoints(f"ipc://{shared}/pub", f"ipc://{shared}/sub"), context=context).start()
    fresh = tmp_path / "fresh" / "graph"
    with Proxy(Endpoints(f"ipc://{fresh}/pub", f"ipc://{fresh}/sub"), context=context):
        assert stat.S_IMODE(fresh.stat().st_mode) == 0o700
