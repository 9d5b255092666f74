"""The node runtime on loopback: heartbeat, readiness gate with buffering, stop path."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import threading
import time
from typing import Any

import pytest
import zmq

from vibrissa.msgs import EndOfStream, NodeStatus, RobotPose
from vibrissa.runtime import Node
from vibrissa.runtime.node import NodeError
from vibrissa.wire import STATUS_TOPIC, Endpoints, Subscriber

TIMEOUT_S = 30.0  # a deadline: heartbeat threads starved on a loaded machine


def node(name: str, endpoints: Endpoints, namespace: str = "/w0", **kw: Any) -> Node:
    return Node(name, namespace, endpoints=endpoints, handle_signals=False, **kw)


def pose(i: int) -> RobotPose:
    return RobotPose(stamp=float(i), frame_id="world", child_frame_id="base",
                     position=[0.0, 0.0, 0.001 * i], orientation=[0.0, 0.0, 0.0, 1.0])


def test_heartbeat_reports_state_counters_and_topics(endpoints: Endpoints) -> None:
    ctx: zmq.Context[Any] = zmq.Context()
    with Subscriber({STATUS_TOPIC: NodeStatus}, endpoints, ctx) as watcher, \
            node("sensor", endpoints, heartbeat_s=0.1, remaps={"raw": "/sim/raw"}) as sensor:
        sensor.create_publisher("raw", EndOfStream)
        sensor.create_subscriber({"cmd": None})
        sensor.counters.update(batches=3)
        sensor.set_state("running", "sampling")
        deadline = time.monotonic() + TIMEOUT_S
        status = None
        while time.monotonic() < deadline:
            rx = watcher.receive(0.2)
            if rx is not None and isinstance(rx.msg, NodeStatus) and rx.msg.state == "running":
                status = rx.msg
                break
        assert status is not None
        assert status.node == "/w0/sensor" and status.message == "sampling"
        assert status.publishes == {"/sim/raw": EndOfStream.TYPE_NAME}
        assert status.subscribes == {"/w0/cmd": "*"}
        assert {"received", "published", "rejected", "lost"} <= set(status.counters)
        assert status.counters["batches"] == 3  # the application's counters ride along
        sensor.close()
        finished = [rx.msg for _ in range(20) if (rx := watcher.receive(0.2)) is not None
                    and isinstance(rx.msg, NodeStatus) and rx.msg.state == "finished"]
        assert finished, "the final status says finished"
    ctx.destroy(linger=0)


def test_gate_buffers_until_the_downstream_node_is_ready(endpoints: Endpoints) -> None:
    n = 500
    with node("source", endpoints) as source:
        pub = source.create_publisher("data", RobotPose, wait_for=["sink"])
        for i in range(n):  # nobody listens yet: these must be buffered, not dropped
            pub.publish(pose(i))
        assert pub.held and pub.pending == n
        time.sleep(0.3)  # pings go out meanwhile and are lost: they must not count as loss
        with node("sink", endpoints, heartbeat_s=0.1) as sink:
            sub = sink.create_subscriber({"/w0/data": RobotPose})
            got: list[int] = []
            deadline = time.monotonic() + TIMEOUT_S
            while len(got) < n and time.monotonic() < deadline:
                rx = sub.receive(0.1)
                if rx is not None:
                    assert isinstance(rx.msg, RobotPose)
                    got.append(int(rx.msg.stamp))
            assert got == list(range(n))
            assert source.wait_for_subscribers("data", ["sink"], 0.1)
            assert sub.counters["/w0/data"].lost == 0 and sub.counters["/w0/data"].pings >= 1
            assert "/w0/data" in sink.status().seen_topics
            assert source.status().counters["published"] == n


def test_a_respawned_publisher_waits_for_its_own_path_not_the_topic(endpoints: Endpoints) -> None:
    """A node restarted on a topic its subscriber has seen: the gate waits until the
    subscriber hears the new publisher (once it opened on the topic alone, and the
    subscriber, busy and not yet connected to the new publisher, lost the first messages)."""
    with node("sink", endpoints, heartbeat_s=0.1) as sink:
        sub = sink.create_subscriber({"/w0/data": RobotPose})
        with node("source", endpoints) as first:
            pub = first.create_publisher("data", RobotPose, wait_for=["sink"])
            pub.publish(pose(0))
            deadline = time.monotonic() + TIMEOUT_S
            while (rx := sub.receive(0.1)) is None and time.monotonic() < deadline:
                pass
            assert rx is not None and "/w0/data" in sink.status().seen_topics
        with node("source", endpoints) as second:  # the respawn: a new publisher id
            pub = second.create_publisher("data", RobotPose, wait_for=["sink"])
            for i in range(1, 11):
                pub.publish(pose(i))
            # the sink takes nothing (a node busy fitting a map): the gate holds
            assert not second.wait_for_subscribers("data", ["sink"], 1.5)
            assert pub.held and pub.pending == 10
            got: list[int] = []
            deadline = time.monotonic() + TIMEOUT_S
            while len(got) < 10 and time.monotonic() < deadline:
                if (rx := sub.receive(0.1)) is not None:
                    got.append(int(rx.msg.stamp))
            assert got == list(range(1, 11))
            assert f"{pub.pub_id:016x}" in sink.status().seen_publishers
    assert sum(c.lost for c in sub.counters.values()) == 0


def test_wait_for_subscribers_times_out_and_keeps_buffering(endpoints: Endpoints) -> None:
    with node("lonely", endpoints) as lonely:
        pub = lonely.create_publisher("out", EndOfStream)
        with pytest.raises(ValueError, match="no publisher"):
            lonely.wait_for_subscribers("other", ["x"], 0.1)
        t0 = time.monotonic()
        assert not lonely.wait_for_subscribers("out", ["/nobody"], 0.3)
        assert 0.25 < time.monotonic() - t0 < 2.0
        pub.publish(EndOfStream(stamp=0.0, source="x", count=0))
        assert pub.pending == 1
        lonely.close(drain_s=0.1)


def test_a_stop_while_held_messages_wait_at_close_cuts_the_wait_short(
        endpoints: Endpoints) -> None:
    """close(drain_s=60) holds a gated message for its subscriber; a stop request (a signal)
    that comes meanwhile ends the wait within a second or two, not after 60 s."""
    with node("lonely", endpoints) as lonely:
        pub = lonely.create_publisher("out", EndOfStream, wait_for=["/nobody"])
        pub.publish(EndOfStream(stamp=0.0, source="x", count=0))
        threading.Timer(0.5, lonely.request_stop).start()
        t0 = time.monotonic()
        lonely.close(drain_s=60.0)
        assert 0.4 < time.monotonic() - t0 < 10.0


def test_a_gate_says_when_its_node_runs_but_subscribes_elsewhere(
        endpoints: Endpoints, caplog: pytest.LogCaptureFixture) -> None:
    """A replay whose topic the downstream node does not take (a missing remap) is told so
    while it waits, not only when the wait times out."""
    with node("source", endpoints) as source, node("sink", endpoints, heartbeat_s=0.1) as sink:
        source.create_publisher("/robot/data", RobotPose, wait_for=["sink"])
        sink.create_subscriber({"/w0/data": RobotPose})
        sink.set_state("running")
        assert not source.wait_for_subscribers("/robot/data", ["sink"], 1.5)
    told = [r.getMessage() for r in caplog.records if "does not subscribe" in r.getMessage()]
    assert told == ["/w0/source: /w0/sink runs but does not subscribe to /robot/data (it "
                    "subscribes to /w0/data): a remap or a namespace may be missing"]


def test_close_does_not_hang_on_a_socket_the_application_forgot(endpoints: Endpoints) -> None:
    n = node("careless", endpoints)
    Subscriber(None, n.endpoints, n.context)  # never closed by the application
    t0 = time.monotonic()
    n.close()
    assert time.monotonic() - t0 < 2.5


def test_messages_published_just_before_close_arrive(endpoints: Endpoints) -> None:
    n = 2000
    with node("sink", endpoints, heartbeat_s=0.1) as sink:
        sub = sink.create_subscriber({"/w0/burst": RobotPose})
        source = node("source", endpoints)
        pub = source.create_publisher("burst", RobotPose)
        received = 0
        ready = False
        pub.hold()
        while not ready:  # the explicit, blocking form of the gate
            ready = source.wait_for_subscribers("burst", ["sink"], 0.05)
            received += sub.receive(0.05) is not None
        for i in range(n):
            pub.publish(pose(i))
        source.close()  # returns only once the queue left (or drain_s ran out)
        while sub.receive(0.5) is not None:
            received += 1
        assert received == n and sub.counters["/w0/burst"].lost == 0


def test_signals_set_the_stop_flag_and_are_restored(endpoints: Endpoints) -> None:
    before = signal.getsignal(signal.SIGTERM)
    with Node("n", endpoints=endpoints) as n:
        assert not n.stop_requested and n.sleep(0.01)
        os.kill(os.getpid(), signal.SIGTERM)
        deadline = time.monotonic() + TIMEOUT_S
        while not n.stop_requested and time.monotonic() < deadline:
            time.sleep(0.01)
        assert n.stop_requested
        assert not n.sleep(5.0)  # returns at once once stopped
    assert signal.getsignal(signal.SIGTERM) is before


@pytest.mark.parametrize("seconds", [1e300, math.inf])
def test_a_sleep_of_any_length_ends_when_stopped(endpoints: Endpoints, seconds: float) -> None:
    """A wrench source at rate_hz 1e-300 sleeps 1e300 s between samples: beyond what threading's
    waits take (OverflowError stopped the node before); it sleeps until stopped."""
    with node("n", endpoints) as n:
        threading.Timer(0.3, n.request_stop).start()
        assert not n.sleep(seconds) and n.stop_requested


def test_exception_in_the_node_reports_error(endpoints: Endpoints) -> None:
    with pytest.raises(RuntimeError):
        with node("crash", endpoints) as crash:
            raise RuntimeError("boom")
    assert crash.state == "error"
    with pytest.raises(ValueError, match="state"):
        crash.set_state("sleeping")


def test_inside_default_actions_a_signal_ends_a_native_call_at_once() -> None:
    """A C call that holds the interpreter (here sum over a huge range) runs no Python
    handler; inside ``default_actions`` SIGINT still ends the process within a second."""
    script = (
        "import sys\n"
        "from vibrissa.runtime.signals import SignalHandlers, default_actions\n"
        "with SignalHandlers(lambda s: None):\n"
        "    with default_actions():\n"
        "        print('busy', flush=True)\n"
        "        sum(range(10**12))\n"
        "print('returned', flush=True)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline() == "busy\n"
    time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    sent = time.monotonic()
    try:
        rc = proc.wait(5)
    finally:
        proc.kill()
    assert rc == -signal.SIGINT
    assert time.monotonic() - sent < 1.0


def test_a_failed_heartbeat_stops_the_node_and_fails_its_with_block(
    endpoints: Endpoints, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Once a status that could not be encoded ended the heartbeat thread, the node stopped
    and exited 0, as if its work were done; the launcher then carried on without it."""
    with pytest.raises(NodeError, match="heartbeat thread failed: ValueError: unencodable"):
        with node("beat", endpoints) as n:
            def broken() -> NodeStatus:
                raise ValueError("unencodable")
            monkeypatch.setattr(n, "status", broken)
            n._beat_now.set()
            deadline = time.monotonic() + 5
            while not n.stop_requested and time.monotonic() < deadline:
                time.sleep(0.01)
            assert n.stop_requested


def test_a_lost_tail_shows_within_a_heartbeat(endpoints: Endpoints) -> None:
    """The end of a stream dropped on its way (as a full send queue drops it, silently for the
    sender): the next heartbeat's ping carries the next seq, and the subscriber counts it."""
    with node("sink", endpoints) as sink, node("source", endpoints, heartbeat_s=0.2) as source:
        sub = sink.create_subscriber({"/w0/data": RobotPose})
        pub = source.create_publisher("data", RobotPose, wait_for=["sink"])
        deadline = time.monotonic() + TIMEOUT_S
        while not source.wait_for_subscribers("data", ["sink"], 0.05):
            assert sub.receive(0.05) is None and time.monotonic() < deadline  # takes the pings
        for i in range(20):
            pub.publish(pose(i))
        send = pub._socket.send
        pub._socket.send = lambda *args, **kw: None  # type: ignore[method-assign]
        pub.publish_end_of_stream(source.fqn)  # never leaves
        pub._socket.send = send  # type: ignore[method-assign]
        got, deadline = 0, time.monotonic() + TIMEOUT_S
        while sub.counters["/w0/data"].lost == 0 and time.monotonic() < deadline:
            got += sub.receive(0.05) is not None
        assert got == 20
        assert sub.counters["/w0/data"].lost == 1  # the end of stream
