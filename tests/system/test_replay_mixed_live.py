"""A bag with the retired single WhiskerWrench (versions 1 and 2) and WhiskerWrenchArray on one
topic, replayed by real processes.

The wrench source (mode ``replay``) and ``vibrissa bag play`` run as subprocesses on a proxy on
free loopback ports; the test's node ``/probe``, which subscribes WhiskerWrenchArray only,
receives. Every message must arrive byte for byte, in recorded order, a single wrench decoded as
the array of its one row, with one publisher's seq from 0.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import msgpack
import numpy as np
import pytest

from vibrissa.msgs import EndOfStream, Message, WhiskerWrenchArray
from vibrissa.msgs.codec import decode, encode
from vibrissa.runtime import Node
from vibrissa.wire import Endpoints, Received, Subscriber
from vibrissa.wire.bag import BagReader, BagWriter

WRENCH = "/whisker0/wrench"
T0_NS = 1_700_000_000_000_000_000
DT_NS = 10_000_000
N = 60  # 0.59 s of bag time
FAST_DT_NS = 500_000_000  # a bag replayed as fast as it goes: 29.5 s of bag time
FAST_SPAN_S = 5.0
"""A replay as fast as it goes spans less than this (paced, the same bag spans 29.5 s): the
bound tells no pacing from pacing on a machine under any load."""
TIMEOUT_S = 30.0


def _array(values: np.ndarray) -> dict[str, object]:
    return {"dtype": "<f8", "shape": list(values.shape), "data": values.tobytes()}


def payload(i: int) -> bytes:
    """Every third message an array of 1-4 whiskers, the others a retired single WhiskerWrench
    as it went on the wire (written out; every seventh of version 1, its pose's frame in
    frame_id)."""
    rng = np.random.default_rng(i)
    if i % 3 == 0:
        n = 1 + i % 4
        return encode(WhiskerWrenchArray(
            stamp=1.0 + 0.01 * i, seq=i // 3, pose_frame_id="world",
            frame_ids=[f"w{k}/clamp" for k in range(n)], whisker_ids=[f"w{k}" for k in range(n)],
            clamp_position=rng.normal(size=(n, 3)),
            clamp_orientation=np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
            f0=rng.normal(size=(n, 3)), m0=rng.normal(size=(n, 3))))
    version = 1 if i % 7 == 0 else 2
    frames = {"frame_id": "world"} if version == 1 else {"frame_id": "w0/clamp",
                                                         "pose_frame_id": "world"}
    return msgpack.packb({  # type: ignore[no-any-return]
        "_type": "vibrissa/WhiskerWrench", "_v": version, "stamp": 1.0 + 0.01 * i, "seq": i,
        "whisker_id": "w0", **frames, "f0": _array(rng.normal(size=3)),
        "m0": _array(rng.normal(size=3)), "clamp_position": _array(rng.normal(size=3)),
        "clamp_orientation": _array(np.array([0.0, 0.0, 0.0, 1.0]))})


def write_mixed_bag(path: Path, end_of_stream: bool, dt_ns: int = DT_NS
                    ) -> list[tuple[type[Message], bytes]]:
    """N mixed messages on ``WRENCH``, ``dt_ns`` apart (and an EndOfStream); returns (type
    decoded as, payload) written."""
    written: list[tuple[type[Message], bytes]] = []
    with BagWriter(path) as bag:
        for i in range(N):
            data = payload(i)
            bag.write(WRENCH, data, T0_NS + i * dt_ns)
            written.append((type(decode(data)), data))
        if end_of_stream:
            eos = encode(EndOfStream(stamp=2.0, source="/recorded", count=N))
            bag.write(WRENCH, eos, T0_NS + N * dt_ns)
            written.append((EndOfStream, eos))
    return written


def test_bag_holds_both_types_on_one_topic(tmp_path: Path) -> None:
    path = tmp_path / "mixed.mcap"
    written = write_mixed_bag(path, end_of_stream=True)
    assert [r.payload for r in BagReader(path)] == [p for _, p in written]
    assert {t.type_name: t.count for t in BagReader(path).info().topics} == {
        "vibrissa/WhiskerWrench": 40, WhiskerWrenchArray.TYPE_NAME: 20,
        EndOfStream.TYPE_NAME: 1}
    assert {t for t, _ in written} == {WhiskerWrenchArray, EndOfStream}


@pytest.fixture
def probe(endpoints: Endpoints) -> Iterator[Subscriber]:
    """The subscriber of the test's node ``/probe`` to ``WRENCH`` (WhiskerWrenchArray): the
    node reports it in its status, which the readiness gates wait for."""
    node = Node("probe", endpoints=endpoints, handle_signals=False)
    yield node.create_subscriber({WRENCH: WhiskerWrenchArray})
    node.close(drain_s=0.0)


def run(endpoints: Endpoints, *args: str) -> subprocess.Popen[str]:
    """``python ARGS`` with the proxy's endpoints in its environment."""
    env = {**os.environ, **endpoints.to_env()}
    return subprocess.Popen([sys.executable, *args], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def receive_until_end(sub: Subscriber, proc: subprocess.Popen[str]
                      ) -> tuple[list[Received], str]:
    """What ``sub`` receives up to the first EndOfStream, and the process's output."""
    got: list[Received] = []
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        rx = sub.receive(0.2)
        if rx is not None:
            got.append(rx)
            if isinstance(rx.msg, EndOfStream):
                break
    try:
        out, _ = proc.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    assert proc.returncode == 0, out
    assert sub.totals()["lost"] == 0 and sub.totals()["rejected"] == 0, out
    return got, out


def check_replayed(got: list[Received], written: list[tuple[type[Message], bytes]],
                   out: str) -> None:
    """Identical bytes, in order, each decoded as the array type (a single wrench: one row), one
    publisher's seq 0, 1, ..."""
    assert [(type(rx.msg), rx.payload) for rx in got[:-1]] == written[:N], out
    assert [rx.msg == decode(p) for rx, (_, p) in zip(got[:-1], written, strict=False)] == [True] * N
    assert sum(len(rx.msg.whisker_ids) == 1 and rx.msg.frame_ids == ["w0/clamp"]  # type: ignore[attr-defined]
               for rx in got[:-1]) >= 40
    assert [rx.header.seq for rx in got] == list(range(N + 1))
    assert len({rx.header.pub for rx in got}) == 1 and {rx.topic for rx in got} == {WRENCH}
    assert isinstance(got[-1].msg, EndOfStream)


@pytest.mark.parametrize(("rate", "end_of_stream"), [(0.0, True), (2.0, False)])
def test_wrench_source_replays_mixed_types_in_order(
    tmp_path: Path, endpoints: Endpoints, probe: Subscriber, rate: float, end_of_stream: bool
) -> None:
    path = tmp_path / "mixed.mcap"
    written = write_mixed_bag(path, end_of_stream, DT_NS if rate else FAST_DT_NS)
    proc = run(endpoints, "-m", "vibrissa.nodes.wrench_source", "--name", "wrench_source",
               "--param", "mode:=replay", "--param", f"bag:={path}",
               "--param", f"replay_rate:={rate}", "--param", "wait_for:=[/probe]",
               "--param", "wait_timeout_s:=20")
    got, out = receive_until_end(probe, proc)
    check_replayed(got, written, out)
    eos = got[-1]
    if end_of_stream:  # the recorded one, byte for byte
        assert eos.payload == written[-1][1]
    else:  # its own, counting every data message it sent
        assert isinstance(eos.msg, EndOfStream)
        assert eos.msg.source == "/wrench_source" and eos.msg.count == N
    span = got[-2].receive_time - got[0].receive_time
    if rate:  # 0.59 s of bag time at 2x
        assert 0.2 < span < 1.2, span
    else:
        assert span < FAST_SPAN_S, span


@pytest.mark.parametrize("gated", [True, False])
def test_bag_play_replays_mixed_types_in_order(
    tmp_path: Path, endpoints: Endpoints, probe: Subscriber, gated: bool
) -> None:
    path = tmp_path / "mixed.mcap"
    written = write_mixed_bag(path, end_of_stream=True, dt_ns=FAST_DT_NS if gated else DT_NS)
    speed = ["--fast", "--wait-for", "/probe"] if gated else ["--rate", "1", "--wait", "1.0"]
    proc = run(endpoints, "-m", "vibrissa.cli.main", "bag", "play", str(path), *speed,
               "--pub", endpoints.pub, "--sub", endpoints.sub)
    got, out = receive_until_end(probe, proc)
    check_replayed(got, written, out)
    assert got[-1].payload == written[-1][1]
    assert f"published {N + 1} messages" in out
    span = got[-2].receive_time - got[0].receive_time
    if gated:
        assert span < FAST_SPAN_S, span
    else:  # 0.59 s of bag time in real time
        assert 0.45 < span < 1.5, span
