"""Publisher -> Proxy -> Subscriber on loopback with free ports; every receive has a timeout."""

from __future__ import annotations

import logging
import time
from typing import Any

import msgpack
import numpy as np
import pytest
import zmq

from vibrissa.msgs import ContactCloud, ContactPointArray, EndOfStream, NodeStatus, Ping, WhiskerWrenchArray
from vibrissa.msgs.codec import encode
from vibrissa.wire import Endpoints, Proxy, Publisher, Subscriber
from vibrissa.wire.transport import BUFFER_ENV, DEFAULT_MAX_BUFFERED_BYTES, MAX_PUBLISHERS

TIMEOUT_S = 2.0


def wrench(seq: int) -> WhiskerWrenchArray:
    return WhiskerWrenchArray(
        stamp=0.001 * seq, seq=seq, whisker_ids=["w0"], frame_ids=["w0/clamp"],
        pose_frame_id="world", clamp_position=[[0.0, 0.0, 0.1]], clamp_orientation=[[0.0, 0.0, 0.0, 1.0]],
        f0=[[0.0, 0.01 * seq, 0.0]], m0=[[0.0, 0.0, 0.0]],
    )


def connect(pub: Publisher, sub: Subscriber) -> None:
    """Ping until the subscriber has seen the topic: the pub -> proxy -> sub path is up."""
    for _ in range(200):
        pub.ping("/test")
        assert sub.receive(0.01) is None  # pings are never handed out
        if pub.topic in sub.seen_topics:
            return
    raise AssertionError(f"subscriber never saw {pub.topic}")


def test_proxy_reports_bound_free_ports(proxy: Proxy) -> None:
    assert proxy.endpoints is not None
    for endpoint in (proxy.endpoints.pub, proxy.endpoints.sub):
        assert endpoint.startswith("tcp://127.0.0.1:") and not endpoint.endswith(":*")
    assert proxy.endpoints.pub != proxy.endpoints.sub


def test_delivers_in_order_without_loss(proxy: Proxy, context: zmq.Context[Any]) -> None:
    n = 2000
    with Publisher("/w0/wrench", WhiskerWrenchArray, proxy.endpoints, context) as pub, \
            Subscriber({"/w0/wrench": WhiskerWrenchArray}, proxy.endpoints, context) as sub:
        connect(pub, sub)
        for i in range(n):
            pub.publish(wrench(i))
        pub.publish_end_of_stream("/test")
        seqs = []
        while (rx := sub.receive(TIMEOUT_S)) is not None:
            if isinstance(rx.msg, EndOfStream):
                assert rx.msg.count == n and rx.header.seq == n
                break
            assert isinstance(rx.msg, WhiskerWrenchArray) and rx.topic == "/w0/wrench"
            assert rx.header.pub == pub.pub_id and rx.header.seq == rx.msg.seq
            assert rx.payload == encode(wrench(rx.msg.seq))
            seqs.append(rx.msg.seq)
        assert seqs == list(range(n))
        counters = sub.counters["/w0/wrench"]
        assert (counters.received, counters.lost, counters.rejected) == (n + 1, 0, 0)
        assert pub.published == n and pub.sent == n + 1


@pytest.mark.parametrize("hwm", [1, 10])
def test_exact_loss_count_when_the_subscriber_falls_behind(
    hwm: int, context: zmq.Context[Any], caplog: pytest.LogCaptureFixture
) -> None:
    n = 20000
    with Proxy(Endpoints.free(), context=context, hwm=hwm) as proxy, \
            Publisher("/fast", WhiskerWrenchArray, proxy.endpoints, context, hwm=hwm) as pub, \
            Subscriber({"/fast": WhiskerWrenchArray}, proxy.endpoints, context, hwm=hwm) as sub:
        connect(pub, sub)
        for i in range(n):  # nobody is receiving: queues overflow, ZeroMQ drops
            pub.publish(wrench(i))
        data = 0
        with caplog.at_level(logging.WARNING, logger="vibrissa.wire.transport"):
            while (rx := sub.receive(0.5)) is not None:  # drain what survived
                data += 1
            pub.publish_end_of_stream("/test")  # queues are empty now: this one arrives
            rx = sub.receive(TIMEOUT_S)
        assert rx is not None and isinstance(rx.msg, EndOfStream)
        counters = sub.counters["/fast"]
        assert counters.received == data + 1
        assert counters.lost == n - data > 0
        assert counters.received + counters.lost == pub.sent == n + 1
        print(f"hwm={hwm}: published {n}, received {data}, lost {counters.lost}")
        gaps = [r for r in caplog.records if "lost %d message(s)" in str(r.msg)]
        assert sum(int(str(r.args[1])) for r in gaps if isinstance(r.args, tuple)) == counters.lost
        # the stream's end compares: what it says was sent, what arrived, what was lost
        [end] = sub.ended_streams
        assert (end.sent, end.received, end.lost) == (n, data, n - data)


def test_rejected_payloads_are_counted_and_delivery_goes_on(
    proxy: Proxy, context: zmq.Context[Any], caplog: pytest.LogCaptureFixture
) -> None:
    nan_payload = msgpack.unpackb(encode(wrench(1)))
    nan_payload["f0"]["data"] = np.array([0.0, np.nan, 0.0]).tobytes()
    with Publisher("/w0/wrench", WhiskerWrenchArray, proxy.endpoints, context) as pub, \
            Subscriber({"/w0/wrench": WhiskerWrenchArray}, proxy.endpoints, context) as sub:
        connect(pub, sub)
        with caplog.at_level(logging.WARNING, logger="vibrissa.wire.transport"):
            pub.publish_raw(encode(wrench(0))[:-5])  # truncated: peek passes, decode fails
            pub.publish_raw(msgpack.packb(nan_payload))
            pub.publish(wrench(2))
            rx = sub.receive(TIMEOUT_S)
        assert rx is not None and isinstance(rx.msg, WhiskerWrenchArray) and rx.msg.seq == 2
        counters = sub.counters["/w0/wrench"]
        assert (counters.received, counters.rejected, counters.lost) == (1, 2, 0)
        messages = [r.getMessage() for r in caplog.records]
        assert any("rejected" in m and "malformed" in m for m in messages)
        assert any("rejected" in m and "WhiskerWrenchArray.f0" in m for m in messages)


def test_a_stream_end_counts_what_was_rejected_apart_from_what_was_lost(
    proxy: Proxy, context: zmq.Context[Any], caplog: pytest.LogCaptureFixture
) -> None:
    """A message that arrived and did not decode is rejected, not lost: the stream's end says
    so (received + lost + rejected = sent). An end repeated with nothing sent since is an
    anomaly, not a stream whose every message was lost."""
    nan_payload = msgpack.unpackb(encode(wrench(1)))
    nan_payload["f0"]["data"] = np.array([0.0, np.nan, 0.0]).tobytes()
    with Publisher("/w0/wrench", WhiskerWrenchArray, proxy.endpoints, context) as pub, \
            Subscriber({"/w0/wrench": WhiskerWrenchArray}, proxy.endpoints, context) as sub:
        connect(pub, sub)
        pub.publish(wrench(0))
        pub.publish_raw(msgpack.packb(nan_payload))
        pub.publish(wrench(2))
        pub.publish_end_of_stream("/test")
        with caplog.at_level(logging.WARNING, logger="vibrissa.wire.transport"):
            pub.publish_end_of_stream("/test")  # again: nothing sent since
            got = []
            while (rx := sub.receive(TIMEOUT_S)) is not None and len(got) < 4:
                got.append(rx.msg)
        assert [type(m).__name__ for m in got] == ["WhiskerWrenchArray", "WhiskerWrenchArray",
                                                   "EndOfStream", "EndOfStream"]
        [end] = sub.ended_streams
        assert (end.sent, end.received, end.lost, end.rejected) == (3, 2, 0, 1)
        assert "3 sent, 2 received, 0 lost, 1 rejected" in end.describe()
        counters = sub.counters["/w0/wrench"]
        assert (counters.lost, counters.rejected, counters.anomalies) == (0, 1, 1)
        assert any("EndOfStream from /test" in r.getMessage() and "again" in r.getMessage()
                   for r in caplog.records)
        # the stream goes on after its end, and ends again: counted from its start (as its
        # publisher counts what it sent)
        pub.publish(wrench(3))
        pub.publish_end_of_stream("/test")
        while (rx := sub.receive(TIMEOUT_S)) is not None and not isinstance(rx.msg, EndOfStream):
            pass
        assert [(e.sent, e.received, e.lost, e.rejected) for e in sub.ended_streams] == [
            (3, 2, 0, 1), (4, 3, 0, 1)]
        assert sub.counters["/w0/wrench"].lost == 0


def test_wrong_type_on_a_topic_is_rejected(proxy: Proxy, context: zmq.Context[Any]) -> None:
    with Publisher("/t", ContactPointArray, proxy.endpoints, context) as pub, \
            Subscriber({"/t": WhiskerWrenchArray}, proxy.endpoints, context) as sub:
        connect(pub, sub)
        pub.publish(ContactPointArray(stamp=0, seq=0, whisker_ids=["w"], frame_id="world",
                                      point=[[0, 0, 0]], s1=[0.0], phase=[0], force=[[0, 0, 0]],
                                      status=[0]))
        assert sub.receive(0.3) is None
        assert sub.counters["/t"].rejected == 1


def test_exact_topic_match_and_subscribe_all(proxy: Proxy, context: zmq.Context[Any]) -> None:
    with Publisher("/a", Ping, proxy.endpoints, context) as pub_a, \
            Publisher("/ab", EndOfStream, proxy.endpoints, context) as pub_ab, \
            Subscriber({"/a": None}, proxy.endpoints, context) as only_a, \
            Subscriber(None, proxy.endpoints, context) as everything:
        connect(pub_a, only_a)
        connect(pub_a, everything)
        connect(pub_ab, everything)
        pub_ab.publish(EndOfStream(stamp=1.0, source="/x", count=0))
        pub_a.publish(Ping(stamp=2.0, sender="/x"))  # a Ping is never delivered ...
        pub_a.publish_end_of_stream("/y")  # ... an EndOfStream is
        rx = only_a.receive(TIMEOUT_S)
        assert rx is not None and rx.topic == "/a" and isinstance(rx.msg, EndOfStream)
        assert only_a.receive(0.2) is None  # nothing from /ab
        topics = set()
        while (rx := everything.receive(0.3)) is not None:
            topics.add(rx.topic)
        assert topics == {"/a", "/ab"}
        assert everything.seen_topics == {"/a", "/ab"}
        assert everything.totals()["received"] == 2


def test_publisher_refuses_other_types(context: zmq.Context[Any]) -> None:
    endpoints = Endpoints("tcp://127.0.0.1:1", "tcp://127.0.0.1:2")  # connect is lazy
    with Publisher("/w", WhiskerWrenchArray, endpoints, context) as pub:
        with pytest.raises(TypeError, match="WhiskerWrenchArray"):
            pub.publish(Ping(stamp=0.0, sender="x"))
        with pytest.raises(TypeError, match="Ping"):
            pub.publish_raw(encode(Ping(stamp=0.0, sender="x")))
    with pytest.raises(ValueError, match="absolute"):
        Publisher("relative", WhiskerWrenchArray, endpoints, context)


def test_a_retired_single_type_goes_raw_on_the_publisher_of_its_array(
        proxy: Proxy, context: zmq.Context[Any]) -> None:
    """A bag's WhiskerWrench bytes (a batch of one row) go out unchanged on a WhiskerWrenchArray
    publisher, and arrive as a WhiskerWrenchArray; never on a ContactPointArray publisher."""
    single = msgpack.packb({
        "_type": "vibrissa/WhiskerWrench", "_v": 2, "stamp": 1.0, "seq": 3, "whisker_id": "w0",
        "frame_id": "w0/clamp", **{k: {"dtype": "<f8", "shape": [3], "data": bytes(24)}
                                   for k in ("f0", "m0")}})
    with Publisher("/w0/wrench", WhiskerWrenchArray, proxy.endpoints, context) as pub, \
            Subscriber({"/w0/wrench": WhiskerWrenchArray}, proxy.endpoints, context) as sub:
        connect(pub, sub)
        pub.publish_raw(single)
        rx = sub.receive(TIMEOUT_S)
        assert rx is not None and rx.payload == single and isinstance(rx.msg, WhiskerWrenchArray)
        assert rx.msg.whisker_ids == ["w0"] and rx.msg.seq == 3 and rx.msg.f0.shape == (1, 3)
    with Publisher("/c", ContactPointArray, proxy.endpoints, context) as contacts, \
            pytest.raises(TypeError, match="vibrissa/WhiskerWrench"):
        contacts.publish_raw(single)


def test_held_messages_are_sent_in_order_on_release(
    proxy: Proxy, context: zmq.Context[Any]
) -> None:
    with Publisher("/h", WhiskerWrenchArray, proxy.endpoints, context) as pub, \
            Subscriber({"/h": WhiskerWrenchArray}, proxy.endpoints, context) as sub:
        pub.hold()
        for i in range(5):
            pub.publish(wrench(i))
        assert pub.pending == 5 and pub.sent == 0
        connect(pub, sub)  # pings pass while held
        assert pub.release() == 5 and not pub.held
        got = [rx.msg.seq for _ in range(5) if (rx := sub.receive(TIMEOUT_S)) is not None]
        assert got == [0, 1, 2, 3, 4]  # type: ignore[attr-defined]
        assert sub.counters["/h"].lost == 0


def test_forged_sequence_headers_stay_bounded_and_plausible(
    proxy: Proxy, context: zmq.Context[Any], caplog: pytest.LogCaptureFixture
) -> None:
    """Huge jumps, seqs near 2**64 and a flood of publisher ids: no 2**64 "lost" messages,
    an anomaly count instead, a bounded table, and a status that still encodes."""
    raw = context.socket(zmq.PUB)
    raw.setsockopt(zmq.LINGER, 0)
    raw.setsockopt(zmq.SNDHWM, 100_000)  # the burst below must not overflow the sender
    raw.connect(proxy.endpoints.pub)
    payload = encode(wrench(0))

    def send(pub_id: int, seq: int) -> None:
        raw.send_multipart([b"/w0/wrench\0", msgpack.packb({"pub": pub_id, "seq": seq}),
                            payload])

    try:
        with Subscriber({"/w0/wrench": WhiskerWrenchArray}, proxy.endpoints, context,
                        hwm=100_000) as sub:
            deadline = time.monotonic() + TIMEOUT_S
            while sub.receive(0.05) is None and time.monotonic() < deadline:
                send(1, 0)  # until the subscription is up
            with caplog.at_level(logging.WARNING, logger="vibrissa.wire.transport"):
                for seq in (1, 2**63, 2**64 - 2, 2**64 - 1, 5, 6, 9):
                    send(1, seq)
                n_ids = MAX_PUBLISHERS + 500
                for pub_id in range(2, 2 + n_ids):
                    send(pub_id, 2**62)
                    send(pub_id, 2**62 + 1)
                got = 0
                while sub.receive(1.0) is not None:
                    got += 1
            counters = sub.counters["/w0/wrench"]
            assert got == 7 + 2 * n_ids
            # 1 -> 2**63 -> 2**64-2 and 6 -> ... jumps: anomalies; 2**64-1 -> 5 back: anomaly;
            # 6 -> 9: two lost, plausibly
            assert counters.anomalies == 3 and counters.lost == 2, counters
            assert len(sub._next_seq) == MAX_PUBLISHERS
            status = NodeStatus(stamp=0.0, node="/n", state="running",
                                counters={"lost": counters.lost, "anomalies": counters.anomalies},
                                publishes={}, subscribes={}, seen_topics=[])
            encode(status)
    finally:
        raw.close()


def test_the_proxy_drops_an_oversized_frame_and_its_sender_only(
    context: zmq.Context[Any],
) -> None:
    with Proxy(Endpoints.free(), context=context, max_message_bytes=1 << 20) as proxy, \
            Publisher("/w0/wrench", WhiskerWrenchArray, proxy.endpoints, context) as pub, \
            Subscriber({"/w0/wrench": WhiskerWrenchArray}, proxy.endpoints, context) as sub:
        connect(pub, sub)
        big = context.socket(zmq.PUB)
        big.setsockopt(zmq.LINGER, 0)
        big.connect(proxy.endpoints.pub)
        try:
            time.sleep(0.3)  # the intruder's connection is up
            big.send_multipart([b"/w0/wrench\0", msgpack.packb({"pub": 99, "seq": 0}),
                                b"x" * (10 << 20)])
            time.sleep(0.3)
            pub.publish(wrench(0))
            rx = sub.receive(TIMEOUT_S)
            assert rx is not None and isinstance(rx.msg, WhiskerWrenchArray)  # still connected
            assert sub.receive(0.3) is None  # and the 10 MB frame never came
            counters = sub.counters["/w0/wrench"]
            assert (counters.received, counters.rejected) == (1, 0)
        finally:
            big.close()


def test_messages_lost_before_the_first_one_heard_count_at_the_end_of_the_stream(
    proxy: Proxy, context: zmq.Context[Any]
) -> None:
    """No seq gap shows messages sent before a subscriber heard the first one; the stream's
    EndOfStream (count = messages sent) does."""
    with Publisher("/late", WhiskerWrenchArray, proxy.endpoints, context) as pub:
        for i in range(5):  # nobody hears these: no subscriber exists yet
            pub.publish(wrench(i))
        sub = Subscriber({"/late": WhiskerWrenchArray}, proxy.endpoints, context)
        connect(pub, sub)  # (the first ping it hears announces seq 5)
        for i in range(5, 8):
            pub.publish(wrench(i))
        pub.publish_end_of_stream("/src")
        received = []
        while (rx := sub.receive(TIMEOUT_S)) is not None:
            received.append(rx.msg)
            if isinstance(rx.msg, EndOfStream):
                break
        assert [m.seq for m in received[:-1]] == [5, 6, 7]
        counters = sub.counters["/late"]
        assert counters.lost == 5
        [end] = sub.ended_streams
        assert (end.source, end.sent, end.received, end.lost) == ("/src", 8, 3, 5)
        sub.close()


def test_a_subscriber_that_does_not_read_buffers_at_most_its_byte_bound(
    proxy: Proxy, context: zmq.Context[Any]
) -> None:
    n, points, bound = 60, 20_000, 4 << 20  # 60 clouds of 0.96 MB into a 4 MiB bound
    cloud = ContactCloud(stamp=0.0, frame_id="world", points=np.zeros((points, 3)),
                         normals=np.zeros((points, 3)))
    size = len(encode(cloud))
    with Publisher("/map/cloud", ContactCloud, proxy.endpoints, context, hwm=n + 10) as pub, \
            Subscriber({"/map/cloud": ContactCloud}, proxy.endpoints, context,
                       max_buffered_bytes=bound) as sub:
        connect(pub, sub)
        for _ in range(n):  # nobody reads: the queue fills to its bound, then drops
            pub.publish(cloud)
        deadline = time.monotonic() + 10.0
        while sub.dropped + sub.queued_bytes // size < n and time.monotonic() < deadline:
            time.sleep(0.05)
        queued = sub.queued_bytes
        assert bound - size < queued <= bound, (queued, bound)
        assert sub.dropped == n - queued // size > 0
        data = 0
        while (rx := sub.receive(0.5)) is not None:
            data += 1
        assert data == queued // size
        pub.publish_end_of_stream("/test")  # the queue is empty again: this one arrives
        rx = sub.receive(TIMEOUT_S)
        assert rx is not None and isinstance(rx.msg, EndOfStream)
        [end] = sub.ended_streams  # every dropped message is a counted loss
        assert (end.sent, end.received, end.lost) == (n, data, sub.dropped)


def test_a_subscriber_busy_after_a_long_wait_still_has_its_queue_drained(
    proxy: Proxy, context: zmq.Context[Any]
) -> None:
    # After a long wait in receive the drainer sleeps until the taker leaves: it must then drain
    # again, or what arrives while the taker is busy would pile up in ZeroMQ, not in the queue.
    n, bound = 30, 4 << 20  # 30 clouds of 48 kB: all fit
    cloud = ContactCloud(stamp=0.0, frame_id="world", points=np.zeros((1000, 3)),
                         normals=np.zeros((1000, 3)))
    size = len(encode(cloud))
    with Publisher("/map/cloud", ContactCloud, proxy.endpoints, context, hwm=n + 10) as pub, \
            Subscriber({"/map/cloud": ContactCloud}, proxy.endpoints, context,
                       max_buffered_bytes=bound) as sub:
        connect(pub, sub)
        assert sub.receive(0.3) is None  # 60 drain periods: the drainer is asleep by now
        for _ in range(n):  # the taker is busy elsewhere from here on
            pub.publish(cloud)
        deadline = time.monotonic() + 10.0
        while sub.queued_bytes < n * size and time.monotonic() < deadline:
            time.sleep(0.01)
        # every payload and its topic and header frames
        assert n * size <= sub.queued_bytes < (n + 1) * size and sub.dropped == 0


def test_the_byte_bound_comes_from_the_environment_when_not_given(
    proxy: Proxy, context: zmq.Context[Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(BUFFER_ENV, str(3 << 20))
    with Subscriber({"/a": WhiskerWrenchArray}, proxy.endpoints, context) as sub:
        assert sub.max_buffered_bytes == 3 << 20
    with Subscriber({"/a": WhiskerWrenchArray}, proxy.endpoints, context, max_buffered_bytes=5) as sub:
        assert sub.max_buffered_bytes == 5
    monkeypatch.setenv(BUFFER_ENV, "lots")
    with pytest.raises(ValueError, match="VIBRISSA_MAX_BUFFERED_BYTES='lots' is not an integer"):
        Subscriber({"/a": WhiskerWrenchArray}, proxy.endpoints, context)
    monkeypatch.delenv(BUFFER_ENV)
    with Subscriber({"/a": WhiskerWrenchArray}, proxy.endpoints, context) as sub:
        assert sub.max_buffered_bytes == DEFAULT_MAX_BUFFERED_BYTES
