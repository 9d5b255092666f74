"""Bags on the live graph: record from and play into a Proxy on free loopback ports."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest
import zmq

from vibrissa.cli.main import main as vibrissa_main
from vibrissa.msgs import EndOfStream, RobotPose, WhiskerWrenchArray
from vibrissa.msgs.codec import encode
from vibrissa.nodes.recorder import RecorderParams, RecordResult, record, subscription
from vibrissa.wire import Endpoints, Publisher, Subscriber
from vibrissa.wire.bag import BagReader, BagWriter, play_bag

TIMEOUT_S = 30.0  # a deadline (thread joins, receives until n arrived) on a loaded machine


def wrench(i: int) -> WhiskerWrenchArray:
    return WhiskerWrenchArray(
        stamp=0.01 * i, seq=i, whisker_ids=["w0"], frame_ids=["w0/clamp"],
        pose_frame_id="world", clamp_position=[[0.0, 0.0, 0.1 * i]],
        clamp_orientation=[[0.0, 0.0, 0.0, 1.0]], f0=[[0.0, 0.01 * i, 0.0]], m0=[[1e-3 * i, 0.0, 0.0]],
    )


def pose(i: int) -> RobotPose:
    return RobotPose(stamp=0.01 * i, frame_id="world", child_frame_id="clamp",
                     position=[0.1 * i, 0.0, 0.0], orientation=[0.0, 0.0, 0.0, 1.0])


class Recording:
    """``record`` in a thread; ``recording()`` tells when its subscriber is connected."""

    def __init__(self, params: RecorderParams, endpoints: Endpoints,
                 context: zmq.Context[Any]) -> None:
        self.stop = threading.Event()
        self.result: RecordResult | None = None
        self.sub = Subscriber(subscription(params.topics), endpoints, context)
        self.thread = threading.Thread(target=self._run, args=(params,), daemon=True)
        self.thread.start()

    def _run(self, params: RecorderParams) -> None:
        self.result = record(params, self.sub, self.stop.is_set)

    def join(self) -> RecordResult:
        self.thread.join(TIMEOUT_S)
        assert not self.thread.is_alive(), "recorder did not stop"
        self.sub.close()
        assert self.result is not None
        return self.result


def connect(pub: Publisher, sub: Subscriber) -> None:
    """Ping until ``sub`` has seen the topic (``sub`` read by another thread: poll its set)."""
    deadline = time.monotonic() + TIMEOUT_S
    while pub.topic not in sub.seen_topics:
        assert time.monotonic() < deadline, f"subscriber never saw {pub.topic}"
        pub.ping("/test")
        time.sleep(0.01)


def test_record_then_read_back_bit_identical(
    tmp_path: Path, endpoints: Endpoints, context: zmq.Context[Any]
) -> None:
    # The default grace (1 s of quiet after the end of stream): the poses come through another
    # socket and may trail it; 0.2 s lost the last pose once on a loaded 2-core machine.
    params = RecorderParams(output=str(tmp_path / "rec.mcap"), stop_on_eos=True)
    rec = Recording(params, endpoints, context)
    sent: list[tuple[str, bytes]] = []
    with Publisher("/w0/wrench", WhiskerWrenchArray, endpoints, context) as pw, \
            Publisher("/robot/pose", RobotPose, endpoints, context) as pp:
        connect(pw, rec.sub)
        connect(pp, rec.sub)
        for i in range(200):
            pw.publish(wrench(i))
            sent.append(("/w0/wrench", encode(wrench(i))))
            if i % 4 == 0:
                pp.publish(pose(i))
                sent.append(("/robot/pose", encode(pose(i))))
        pw.publish_end_of_stream("/test")
        result = rec.join()  # pose never ends: end of stream on /w0/wrench is enough
    assert result.reason == "end of stream" and result.lost == 0
    got = [(r.topic, r.payload) for r in BagReader(params.output)]
    for topic in ("/w0/wrench", "/robot/pose"):  # two sockets: order holds per topic only
        assert [p for t, p in got if t == topic] == [p for t, p in sent if t == topic] + (
            [got[-1][1]] if topic == "/w0/wrench" else [])
    assert BagReader(params.output).info().types["vibrissa/EndOfStream"] == 1
    seqs = [r.sequence for r in BagReader(params.output, topics=["/w0/wrench"])]
    assert seqs == list(range(201))


def test_record_only_named_topics_for_a_duration(
    tmp_path: Path, endpoints: Endpoints, context: zmq.Context[Any]
) -> None:
    params = RecorderParams(output=str(tmp_path / "rec.mcap"), topics=("/w0/wrench",),
                            duration_s=1.0)
    rec = Recording(params, endpoints, context)
    with Publisher("/w0/wrench", WhiskerWrenchArray, endpoints, context) as pw, \
            Publisher("/robot/pose", RobotPose, endpoints, context) as pp:
        connect(pw, rec.sub)
        for i in range(20):
            pw.publish(wrench(i))
            pp.publish(pose(i))
        result = rec.join()
    assert result.reason == "duration"
    info = BagReader(params.output).info()
    assert info.topic_counts == {"/w0/wrench": 20}


def make_bag(path: Path, n: int = 50, dt_ns: int = 10_000_000) -> list[tuple[str, bytes]]:
    written = []
    with BagWriter(path) as bag:
        for i in range(n):
            for topic, payload in (("/w0/wrench", encode(wrench(i))),
                                   ("/robot/pose", encode(pose(i)))):
                bag.write(topic, payload, 1_000_000_000 + i * dt_ns)
                written.append((topic, payload))
        eos = encode(EndOfStream(stamp=1.0, source="/src", count=n))
        bag.write("/w0/wrench", eos, 1_000_000_000 + n * dt_ns)
        written.append(("/w0/wrench", eos))
    return written


def per_topic(rows: list[tuple[str, bytes]]) -> dict[str, list[bytes]]:
    """Payloads per topic: one socket per topic keeps order per topic, not across topics."""
    out: dict[str, list[bytes]] = {}
    for topic, payload in rows:
        out.setdefault(topic, []).append(payload)
    return out


def collect(sub: Subscriber, n: int) -> list[tuple[str, bytes, float]]:
    got = []
    while len(got) < n and (rx := sub.receive(TIMEOUT_S)) is not None:
        got.append((rx.topic, rx.payload, rx.receive_time))
    return got


@pytest.mark.parametrize("rate", [None, 1.0])
def test_play_delivers_identical_payloads_in_order(
    tmp_path: Path, endpoints: Endpoints, context: zmq.Context[Any], rate: float | None
) -> None:
    path = tmp_path / "in.mcap"
    # paced: 0.5 s of bag time; as fast as it goes: 25 s, which it must take far less than
    written = make_bag(path, dt_ns=10_000_000 if rate else 500_000_000)
    with Subscriber(None, endpoints, context) as sub:
        result_box: list[Any] = []
        player = threading.Thread(target=lambda: result_box.append(play_bag(
            path, rate=rate, wait_s=0.5, endpoints=endpoints, context=context)))
        player.start()
        got = collect(sub, len(written))
        player.join(TIMEOUT_S)
    assert per_topic([(t, p) for t, p, _ in got]) == per_topic(written)
    assert result_box and result_box[0].total == len(written) and not result_box[0].interrupted
    assert sum(c.lost for c in sub.counters.values()) == 0
    span = got[-1][2] - got[0][2]
    if rate == 1.0:  # 0.5 s of bag time, played in real time
        assert 0.4 < span < 1.5
    else:  # no pacing (on a machine under any load)
        assert span < 5.0


def test_play_topic_filter_and_rate(
    tmp_path: Path, endpoints: Endpoints, context: zmq.Context[Any]
) -> None:
    path = tmp_path / "in.mcap"
    written = make_bag(path, n=20, dt_ns=50_000_000)  # 1 s of bag time
    want = [w for w in written if w[0] == "/robot/pose"]
    with Subscriber(None, endpoints, context) as sub:
        player = threading.Thread(target=play_bag, args=(path,), kwargs=dict(
            rate=4.0, topics=["/robot/pose"], wait_s=0.5, endpoints=endpoints, context=context))
        player.start()
        got = collect(sub, len(want))
        player.join(TIMEOUT_S)
        assert sub.receive(0.2) is None
    assert [(t, p) for t, p, _ in got] == want
    assert 0.15 < got[-1][2] - got[0][2] < 0.6  # 0.95 s of bag time at 4x


def test_play_stops_early(tmp_path: Path, endpoints: Endpoints, context: zmq.Context[Any]) -> None:
    path = tmp_path / "in.mcap"
    make_bag(path, n=20, dt_ns=500_000_000)  # 10 s of bag time
    stop = threading.Event()
    threading.Timer(0.8, stop.set).start()
    t0 = time.monotonic()
    result = play_bag(path, wait_s=0.2, endpoints=endpoints, context=context, stop=stop)
    assert result.interrupted and time.monotonic() - t0 < 3.0
    assert 0 < result.total < 41


def test_play_waits_out_a_jump_of_centuries_until_stopped(
    tmp_path: Path, endpoints: Endpoints, context: zmq.Context[Any]
) -> None:
    """A bag whose log times jump by 2^63 - 1 ns (292 years), played at half speed: a wait of
    584 years, beyond what threading's waits take (OverflowError before); stopped, it ends."""
    path = tmp_path / "far.mcap"
    with BagWriter(path) as bag:
        bag.write("/robot/pose", encode(pose(0)), 0)
        bag.write("/robot/pose", encode(pose(1)), 2**63 - 1)
    assert (2**63 - 1) * 1e-9 / 0.5 > threading.TIMEOUT_MAX
    stop = threading.Event()
    threading.Timer(0.8, stop.set).start()
    result = play_bag(path, rate=0.5, wait_s=0.2, endpoints=endpoints, context=context, stop=stop)
    assert result.interrupted and result.total == 1


def test_cli_record_play_info_export(
    tmp_path: Path, endpoints: Endpoints, context: zmq.Context[Any],
    capsys: pytest.CaptureFixture[str],
) -> None:
    src = tmp_path / "in.mcap"
    written = make_bag(src, n=30, dt_ns=1_000_000)
    flags = ["--pub", endpoints.pub, "--sub", endpoints.sub]
    out = tmp_path / "out.mcap"
    recorder = threading.Thread(target=vibrissa_main, args=(
        ["bag", "record", "-o", str(out), "/w0/wrench", "/robot/pose", "--until-eos",
         "--eos-grace", "0.3", "--duration", "20", *flags],))
    recorder.start()
    time.sleep(0.5)  # let the recorder's subscription reach the proxy
    assert vibrissa_main(["bag", "play", str(src), "--fast", "--wait", "0.5", *flags]) == 0
    recorder.join(TIMEOUT_S + 10)
    assert not recorder.is_alive()
    assert per_topic([(r.topic, r.payload) for r in BagReader(out)]) == per_topic(written)

    capsys.readouterr()
    assert vibrissa_main(["bag", "info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "messages:  61" in text and "/robot/pose" in text

    exported = tmp_path / "out.json.mcap"
    assert vibrissa_main(["bag", "export", str(out), "-o", str(exported)]) == 0
    info = BagReader(exported).info()
    assert info.message_count == len(written)
