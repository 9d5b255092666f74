"""Direct publishers: bound endpoints announced in NodeStatus, one hop, each message once."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import msgpack
import pytest
import zmq

from vibrissa.msgs import EndOfStream, NodeStatus, WhiskerWrenchArray
from vibrissa.msgs.codec import encode
from vibrissa.runtime import Node
from vibrissa.wire import STATUS_TOPIC, Endpoints, Proxy, Publisher, Subscriber

TIMEOUT_S = 5.0
TOPIC = "/w0/wrench"


def wrench(seq: int) -> WhiskerWrenchArray:
    return WhiskerWrenchArray(
        stamp=0.001 * seq, seq=seq, whisker_ids=["w0"], frame_ids=["w0/clamp"],
        pose_frame_id="world", clamp_position=[[0.0, 0.0, 0.1]], clamp_orientation=[[0.0, 0.0, 0.0, 1.0]],
        f0=[[0.0, 0.01 * seq, 0.0]], m0=[[0.0, 0.0, 0.0]],
    )


def connect(pubs: list[Publisher], sub: Subscriber) -> None:
    """Ping until the subscriber has had a ping from every publisher (the paths are up)."""
    deadline = time.monotonic() + TIMEOUT_S
    while {p.pub_id for p in pubs} - {pub for (_, pub) in sub._next_seq}:
        assert time.monotonic() < deadline, "the subscriber never heard every publisher"
        for pub in pubs:
            pub.ping("/test")
        assert sub.receive(0.01) is None  # pings and statuses read for discovery stay inside


def drain(sub: Subscriber, ends: int) -> list[tuple[int, int]]:
    """(publisher id, seq) of every data message until ``ends`` EndOfStreams arrived."""
    got = []
    while ends:
        rx = sub.receive(TIMEOUT_S)
        assert rx is not None, "a message never came"
        if isinstance(rx.msg, EndOfStream):
            ends -= 1
        else:
            got.append((rx.header.pub, rx.header.seq))
    return got


def announce(status: Publisher, pub: Publisher, sub: Subscriber | None = None) -> None:
    """What a node does in its heartbeat: name ``pub``'s direct endpoint in a NodeStatus; with
    ``sub``, until it has connected there and had a ping from ``pub``."""
    assert pub.endpoint is not None
    deadline = time.monotonic() + TIMEOUT_S
    while True:
        status.publish(NodeStatus(stamp=0.0, node="/third_party", state="running", counters={},
                                  publishes={pub.topic: pub.type_name}, subscribes={},
                                  seen_topics=[], endpoints={pub.topic: pub.endpoint}))
        if sub is None or pub.pub_id in {p for (_, p) in sub._next_seq}:
            return
        assert time.monotonic() < deadline, "the subscriber never heard the direct publisher"
        pub.ping("/test")
        sub.receive(0.05)


@pytest.mark.parametrize(("proxy_pub", "expected"), [
    ("tcp://127.0.0.1:7400", "tcp://127.0.0.1:*"),
    ("ipc:///tmp/vib/pub", "ipc:///tmp/vib/pub-00000000000000ff"),
    ("inproc://bus", "inproc://bus-00000000000000ff"),
    ("pgm://eth0;239.192.1.1:5555", None),
])
def test_a_direct_publisher_binds_beside_the_proxy(proxy_pub: str, expected: str | None) -> None:
    assert Endpoints(proxy_pub, "unused").direct_bind(0xFF) == expected


def test_a_node_publisher_is_heard_in_one_hop_and_never_through_the_proxy(
    endpoints: Endpoints, context: zmq.Context[Any]
) -> None:
    n = 500
    raw = context.socket(zmq.SUB)  # a reader that knows the proxy only
    raw.setsockopt(zmq.LINGER, 0)
    raw.setsockopt(zmq.SUBSCRIBE, TOPIC.encode() + b"\0")
    raw.connect(endpoints.sub)
    with Subscriber({TOPIC: WhiskerWrenchArray}, endpoints, context) as sub, \
            Node("talker", endpoints=endpoints, context=context, handle_signals=False) as node:
        pub = node.create_publisher(TOPIC, WhiskerWrenchArray)
        assert pub.endpoint is not None and pub.endpoint.startswith("tcp://127.0.0.1:")
        assert node.status().endpoints == {TOPIC: pub.endpoint}
        connect([pub], sub)
        assert sub.direct_endpoints == {pub.endpoint}
        for i in range(n):
            pub.publish(wrench(i))
        pub.publish_end_of_stream(node.fqn)
        assert drain(sub, 1) == [(pub.pub_id, i) for i in range(n)]
        counters = sub.counters[TOPIC]
        assert (counters.received, counters.lost, counters.rejected) == (n + 1, 0, 0)
        assert raw.poll(200) == 0  # nothing went through the proxy
    raw.close()


def test_direct_and_proxied_publishers_of_one_topic_arrive_once_each(
    endpoints: Endpoints, context: zmq.Context[Any]
) -> None:
    n = 300
    with Subscriber({TOPIC: WhiskerWrenchArray}, endpoints, context) as sub, \
            Publisher(STATUS_TOPIC, NodeStatus, endpoints, context) as status, \
            Publisher(TOPIC, WhiskerWrenchArray, endpoints, context, direct=True) as direct, \
            Publisher(TOPIC, WhiskerWrenchArray, endpoints, context) as proxied:
        assert proxied.endpoint is None
        announce(status, direct, sub)
        connect([direct, proxied], sub)
        for i in range(n):
            direct.publish(wrench(i))
            proxied.publish(wrench(i))
        direct.publish_end_of_stream("/direct")
        proxied.publish_end_of_stream("/proxied")
        got = drain(sub, 2)
        for pub in (direct, proxied):  # each once, in its own order
            assert [seq for (pub_id, seq) in got if pub_id == pub.pub_id] == list(range(n))
        assert len(got) == 2 * n
        counters = sub.counters[TOPIC]
        assert (counters.received, counters.lost) == (2 * n + 2, 0)


@pytest.mark.parametrize("hwm", [1, 10])
def test_exact_loss_count_on_the_direct_path(
    hwm: int, context: zmq.Context[Any], caplog: pytest.LogCaptureFixture
) -> None:
    n = 20000
    with Proxy(Endpoints.free(), context=context) as proxy, \
            Subscriber({"/fast": WhiskerWrenchArray}, proxy.endpoints, context, hwm=hwm) as sub, \
            Publisher(STATUS_TOPIC, NodeStatus, proxy.endpoints, context) as status, \
            Publisher("/fast", WhiskerWrenchArray, proxy.endpoints, context, hwm=hwm,
                      direct=True) as pub:
        announce(status, pub, sub)
        for i in range(n):  # nobody is receiving: queues overflow, ZeroMQ drops
            pub.publish(wrench(i))
        data = 0
        with caplog.at_level(logging.WARNING, logger="vibrissa.wire.transport"):
            while (rx := sub.receive(0.5)) is not None:
                data += 1
            pub.publish_end_of_stream("/test")
            rx = sub.receive(TIMEOUT_S)
        assert rx is not None and isinstance(rx.msg, EndOfStream)
        counters = sub.counters["/fast"]
        assert counters.lost == n - data > 0
        assert counters.received + counters.lost == pub.sent == n + 1


def test_a_publisher_that_cannot_bind_goes_through_the_proxy(
    context: zmq.Context[Any], caplog: pytest.LogCaptureFixture
) -> None:
    elsewhere = Endpoints("tcp://192.0.2.1:7400", "tcp://192.0.2.1:7401")  # not this machine
    with caplog.at_level(logging.WARNING, logger="vibrissa.wire.transport"), \
            Publisher(TOPIC, WhiskerWrenchArray, elsewhere, context, direct=True) as pub:
        assert pub.endpoint is None
    assert any("through the proxy" in r.getMessage() for r in caplog.records)


def test_statuses_read_for_discovery_are_not_the_callers(
    endpoints: Endpoints, context: zmq.Context[Any]
) -> None:
    with Subscriber({TOPIC: WhiskerWrenchArray}, endpoints, context) as sub, \
            Publisher(STATUS_TOPIC, NodeStatus, endpoints, context) as status, \
            Publisher(TOPIC, WhiskerWrenchArray, endpoints, context, direct=True) as pub:
        deadline = time.monotonic() + TIMEOUT_S
        while not sub.direct_endpoints:
            assert time.monotonic() < deadline
            announce(status, pub)
            assert sub.receive(0.05) is None
        raw = context.socket(zmq.PUB)  # a malformed status: dropped, not the caller's either
        raw.setsockopt(zmq.LINGER, 0)
        raw.connect(endpoints.pub)
        time.sleep(0.3)  # the proxy forwards the subscription to the new publisher
        raw.send_multipart([STATUS_TOPIC.encode() + b"\0", msgpack.packb({"pub": 1, "seq": 0}),
                            encode(wrench(0))])
        assert sub.receive(0.3) is None
        raw.close()
        assert set(sub.counters) == {TOPIC}
        assert sub.counters[TOPIC].received == 0 and sub.counters[TOPIC].rejected == 0


def test_ipc_socket_files_are_removed_at_close(tmp_path: Path, context: zmq.Context[Any]) -> None:
    requested = Endpoints(f"ipc://{tmp_path}/pub", f"ipc://{tmp_path}/sub")
    with Proxy(requested, context=context) as proxy:
        assert proxy.endpoints is not None
        with Subscriber({TOPIC: WhiskerWrenchArray}, proxy.endpoints, context) as sub, \
                Publisher(STATUS_TOPIC, NodeStatus, proxy.endpoints, context) as status, \
                Publisher(TOPIC, WhiskerWrenchArray, proxy.endpoints, context, direct=True) as pub:
            assert pub.endpoint == f"ipc://{tmp_path}/pub-{pub.pub_id:016x}"
            announce(status, pub, sub)  # the direct path works over ipc
            pub.publish(wrench(7))
            rx = sub.receive(TIMEOUT_S)
            assert rx is not None and rx.header.pub == pub.pub_id and rx.header.seq == 0
            assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
                ["pub", "sub", f"pub-{pub.pub_id:016x}"])
        assert sorted(p.name for p in tmp_path.iterdir()) == ["pub", "sub"]
    assert list(tmp_path.iterdir()) == []
