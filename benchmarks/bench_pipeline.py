"""Latency and throughput of the node graph: wrenches published -> contact points received.

Pipeline (every box its own process, real ZeroMQ on loopback), as nodes connect: node
publishers bind and announce their endpoint in their status on the proxy, subscribers connect
there (docs/ARCHITECTURE.md), so data skips the proxy::

    load --/bench/wrench--> reconstructor --/bench/contact--> sink (here)
    (and their statuses, with the endpoints, through the proxy)

Floor, in the same run, with the same payload and the same pacing::

    load (bare PUB) --> echo (SUB -> PUB, forwards the bytes) --> sink (bare SUB)

the pipeline with CURVE on every socket (``curve``: keys of ``vibrissa keys``, the ZAP guards;
the sink connects with the graph's key), and the floor through the broker (``proxied``): the
same bare processes connected through the proxy, as tools and raw publishers are (what the
broker costs without any work)::

    load --/bench/wrench--> proxy --> echo --/bench/contact--> proxy --> sink

Two ways to send a tick of 32 whiskers at ``rate`` wrenches/s in total: *per wrench*, one
WhiskerWrench per whisker (32 messages per tick; latency per wrench, its ContactPoint), and
*per tick*, one WhiskerWrenchArray of 32 rows (latency per tick, its ContactPointArray). The
load sends pre-encoded payloads and records the send time of each message; the sink records the
receive time of each by sequence number (the transport header's ``seq``, so the sink decodes
nothing). Loss is sent - received (every benchmark wrench has a contact). A rate is
*sustained* when nothing is lost and the sink is done within ``max(50 ms, 5 %)`` of the send
duration after the last send (no backlog grows). ``first p50`` is the median latency of the
first message of each tick (whisker 0 per wrench; every message per tick). With ``--repeat``
every figure is the median over the repeats (runs interleaved), sustained counts the repeats,
and ``pooled p99 x`` is the ratio of the p99 of all repeats' latencies together: a run's p99 is
set by the few stalls of a few ms that happen to fall in it (on a shared VM they hit the floor
as much as the pipeline), and pooling the repeats counts more of them.

Run: ``python benchmarks/bench_pipeline.py [--duration 2] [--rates 1000,...] [--repeat 1]``.
Not a test.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import zmq

from vibrissa.msgs import Ping, peek_type
from vibrissa.wire import Endpoints
from vibrissa.wire.security import Keys, create_keys

WHISKERS = 32
TOPIC = "/bench/wrench"
CONTACT = "/bench/contact"
UNITS = ("wrench", "tick")  # one WhiskerWrench per whisker, or one WhiskerWrenchArray per tick
MODES = ("bare", "proxied", "vibrissa", "curve")
# the floor, the floor through the proxy, the pipeline, the pipeline encrypted and authenticated


# -- helper processes (python bench_pipeline.py _proxy | _load | _echo ...) ----------------------


def _payloads(n: int, unit: str) -> list[bytes]:
    """``n`` encoded messages, seq 0..n-1, cycling over valid wrenches and whiskers: a
    WhiskerWrench each (``unit`` wrench) or a WhiskerWrenchArray of WHISKERS rows (tick)."""
    from vibrissa.msgs import WhiskerWrench, WhiskerWrenchArray, encode
    from vibrissa.reconstruct import reconstruct

    rng = np.random.default_rng(1)
    p0, f0, m0 = rng.uniform(-1, 1, (512, 3)), rng.normal(size=(512, 3)), rng.normal(size=(512, 3))
    valid = np.flatnonzero(reconstruct(p0, f0, m0).valid)
    out = []
    for i in range(n):
        if unit == "tick":
            k = valid[np.arange(i * WHISKERS, (i + 1) * WHISKERS) % len(valid)]
            out.append(encode(WhiskerWrenchArray(
                stamp=0.0, seq=i, pose_frame_id="world", frame_ids=[f"whisker{j}/clamp" for j in range(WHISKERS)],
                whisker_ids=[f"whisker{j}" for j in range(WHISKERS)], clamp_position=p0[k],
                clamp_orientation=np.tile([0.0, 0.0, 0.0, 1.0], (WHISKERS, 1)), f0=f0[k],
                m0=m0[k])))
            continue
        k = valid[i % len(valid)]
        out.append(encode(WhiskerWrench(
            stamp=0.0, seq=i, whisker_id=f"whisker{i % WHISKERS}",
            frame_id=f"whisker{i % WHISKERS}/clamp", pose_frame_id="world",
            clamp_position=p0[k], clamp_orientation=[0.0, 0.0, 0.0, 1.0], f0=f0[k], m0=m0[k])))
    return out


def _per_tick(unit: str) -> int:
    """Messages per tick."""
    return WHISKERS if unit == "wrench" else 1


def _pace(send: Any, n: int, rate: float, per_tick: int, t_send: np.ndarray) -> None:
    """Call ``send(i)`` for i < n, ``per_tick`` messages per tick, ticks of WHISKERS wrenches
    at ``rate`` wrenches/s."""
    tick = WHISKERS / rate
    t0 = time.perf_counter() + 0.05
    clock_offset = time.time() - time.perf_counter()
    for start in range(0, n, per_tick):
        due = t0 + (start // per_tick) * tick
        delay = due - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        for i in range(start, min(n, start + per_tick)):
            t_send[i] = time.perf_counter() + clock_offset
            send(i)


def _load(mode: str, unit: str, endpoint: str, n: int, rate: float, out: str) -> None:
    payloads = _payloads(n, unit)
    per_tick = _per_tick(unit)
    t_send = np.zeros(n)
    if mode in ("bare", "proxied"):
        context: zmq.Context[Any] = zmq.Context()
        sock = context.socket(zmq.PUB)
        sock.setsockopt(zmq.SNDHWM, n + 10)
        sock.setsockopt(zmq.LINGER, 2000)
        if mode == "bare":
            sock.bind(endpoint)
        else:
            sock.connect(endpoint)
        prefix = TOPIC.encode() + b"\0"
        print("ready", flush=True)
        sys.stdin.readline()  # the bench says go once the chain is connected

        def send_bare(i: int) -> None:
            sock.send_multipart((prefix, i.to_bytes(8, "little"), payloads[i]))

        _pace(send_bare, n, rate, per_tick, t_send)
        sock.close()
        context.term()
    else:
        from vibrissa.msgs import WhiskerWrench, WhiskerWrenchArray
        from vibrissa.runtime import Node

        msg_type = WhiskerWrench if unit == "wrench" else WhiskerWrenchArray
        with Node("load", "/bench", handle_signals=False) as node:
            pub = node.create_publisher("wrench", msg_type, wait_for=["reconstructor"],
                                        hwm=n + 10)
            if not node.wait_for_subscribers("wrench", ["reconstructor"], 60.0):
                raise SystemExit("reconstructor not ready")
            print("ready", flush=True)
            sys.stdin.readline()
            _pace(lambda i: pub.publish_raw(payloads[i]), n, rate, per_tick, t_send)
            pub.publish_end_of_stream(node.fqn)
    np.save(out, t_send)


def _echo(source: str, endpoint: str, via_proxy: bool) -> None:
    """Forward every message; ``via_proxy``: connect to the proxy's ``endpoint`` and forward
    /bench/wrench as /bench/contact, else bind ``endpoint`` and forward as it came."""
    context: zmq.Context[Any] = zmq.Context()
    sub, pub = context.socket(zmq.SUB), context.socket(zmq.PUB)
    for sock in (sub, pub):
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.RCVHWM, 1_000_000)
        sock.setsockopt(zmq.SNDHWM, 1_000_000)
    sub.setsockopt(zmq.SUBSCRIBE, TOPIC.encode() + b"\0" if via_proxy else b"")
    if via_proxy:
        pub.connect(endpoint)
    else:
        pub.bind(endpoint)
    sub.connect(source)
    out_topic = CONTACT.encode() + b"\0"
    try:
        while True:
            frames = sub.recv_multipart()
            if via_proxy:
                frames[0] = out_topic
            pub.send_multipart(frames)
    except KeyboardInterrupt:
        pass
    finally:
        sub.close()
        pub.close()
        context.term()


def _proxy() -> None:
    from vibrissa.wire.security import Keys
    from vibrissa.wire.transport import Proxy

    proxy = Proxy(Endpoints.free().with_keys(Keys.from_env()), zmq.Context(), hwm=1_000_000)
    bound = proxy.start()
    print(bound.pub, bound.sub, flush=True)
    try:
        sys.stdin.readline()  # until the bench closes our stdin
    except KeyboardInterrupt:
        pass
    finally:
        proxy.stop()


# -- the bench ------------------------------------------------------------------------------------


@dataclass
class Run:
    """One measured run (``sent``, ``received``: messages; ``rate``: wrenches/s)."""

    mode: str
    unit: str
    rate: float
    sent: int
    received: int
    latency_s: np.ndarray
    first_latency_s: np.ndarray
    send_s: float
    backlog_s: float

    @property
    def lost(self) -> int:
        return self.sent - self.received

    @property
    def sustained(self) -> bool:
        return self.lost == 0 and self.backlog_s <= max(0.05, 0.05 * self.send_s)

    def pct(self, q: float, first: bool = False) -> float:
        """Percentile ``q`` of the latency, us (``first``: of the first message of each tick)."""
        latency = self.first_latency_s if first else self.latency_s
        return float(np.percentile(latency, q)) * 1e6 if len(latency) else np.nan


def _python(*args: str, **kwargs: Any) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, *args], text=True, **kwargs)


def _sink(sock: zmq.Socket[Any], n: int, header_seq: bool, timeout_s: float) -> np.ndarray:
    """Receive times (time.time(), s) by sequence number; NaN where nothing came."""
    t_recv = np.full(n, np.nan)
    got = 0
    idle_until = time.monotonic() + timeout_s
    while got < n:
        remaining = idle_until - time.monotonic()
        if remaining <= 0 or not sock.poll(int(remaining * 1000)):
            break
        frames = sock.recv_multipart()
        now = time.time()
        if header_seq and peek_type(frames[2])[0] == Ping.TYPE_NAME:
            continue  # a node's keep-alive ping: it carries the next seq, not a message
        seq = (msgpack.unpackb(frames[1])["seq"] if header_seq
               else int.from_bytes(frames[1], "little"))
        if seq < n:
            t_recv[seq] = now
            got += 1
        idle_until = time.monotonic() + 5.0
    return t_recv


def _announced(endpoints: Endpoints, node: str, topic: str, timeout_s: float = 30.0) -> str:
    """The direct endpoint ``node`` announces for ``topic`` in its status (a subscriber that
    reads nothing else connects there, as ``Subscriber`` does)."""
    from vibrissa.msgs import NodeStatus
    from vibrissa.wire import STATUS_TOPIC, Subscriber

    with Subscriber({STATUS_TOPIC: NodeStatus}, endpoints) as statuses:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            rx = statuses.receive(0.1)
            if rx is not None and isinstance(rx.msg, NodeStatus) and rx.msg.node == node \
                    and topic in rx.msg.endpoints:
                return rx.msg.endpoints[topic]
    raise SystemExit(f"{node} announced no endpoint for {topic} within {timeout_s} s")


def measure(mode: str, unit: str, rate: float, duration_s: float, tmp: Path) -> Run:
    """One run of the pipeline (``mode`` = ``vibrissa``), the floor (``bare``) or the floor
    through the proxy (``proxied``), sending a message per wrench or per tick (``unit``) at
    ``rate`` wrenches/s."""
    per_tick = _per_tick(unit)
    n = int(rate * duration_s) // WHISKERS * per_tick
    out = tmp / f"send-{mode}-{unit}-{int(rate)}.npy"
    context: zmq.Context[Any] = zmq.Context()
    sink = context.socket(zmq.SUB)
    sink.setsockopt(zmq.LINGER, 0)
    sink.setsockopt(zmq.RCVHWM, 1_000_000)
    helpers: list[subprocess.Popen[str]] = []
    me = str(Path(__file__).resolve())
    try:
        if mode == "bare":
            probe = context.socket(zmq.PUB)  # find two free ports
            load_ep = f"tcp://127.0.0.1:{probe.bind_to_random_port('tcp://127.0.0.1')}"
            echo_ep = f"tcp://127.0.0.1:{probe.bind_to_random_port('tcp://127.0.0.1')}"
            probe.close()
            load = _python(me, "_load", "bare", unit, load_ep, str(n), str(rate), str(out),
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE)
            helpers.append(load)
            assert load.stdout is not None and load.stdout.readline().strip() == "ready"
            helpers.append(_python(me, "_echo", load_ep, echo_ep, "direct"))
            sink.setsockopt(zmq.SUBSCRIBE, b"")
            sink.connect(echo_ep)
            time.sleep(1.5)  # slow joiners: both subscriptions reach their publishers
            header_seq = False
        elif mode == "proxied":
            proxy = _python(me, "_proxy", stdin=subprocess.PIPE, stdout=subprocess.PIPE)
            helpers.append(proxy)
            assert proxy.stdout is not None
            pub_ep, sub_ep = proxy.stdout.readline().split()
            sink.setsockopt(zmq.SUBSCRIBE, CONTACT.encode() + b"\0")
            sink.connect(sub_ep)
            helpers.append(_python(me, "_echo", sub_ep, pub_ep, "proxy"))
            load = _python(me, "_load", "proxied", unit, pub_ep, str(n), str(rate), str(out),
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE)
            helpers.append(load)
            assert load.stdout is not None and load.stdout.readline().strip() == "ready"
            time.sleep(1.5)
            header_seq = False
        else:
            keys = None
            secured: dict[str, str] = {}
            if mode == "curve":
                create_keys(tmp / "keys")
                keys = Keys.load(tmp / "keys")
                keys.connect_with(sink)
                secured = keys.to_env()
            env = {**os.environ, "VIBRISSA_LOG_LEVEL": "WARNING", **secured}
            proxy = _python(me, "_proxy", stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
            helpers.append(proxy)
            assert proxy.stdout is not None
            pub_ep, sub_ep = proxy.stdout.readline().split()
            env.update({"VIBRISSA_PUB_ENDPOINT": pub_ep, "VIBRISSA_SUB_ENDPOINT": sub_ep})
            sink.setsockopt(zmq.SUBSCRIBE, CONTACT.encode() + b"\0")
            sink.connect(sub_ep)
            helpers.append(_python("-m", "vibrissa.nodes.reconstructor", "--name",
                                   "reconstructor", "--namespace", "/bench", env=env))
            sink.connect(_announced(Endpoints(pub_ep, sub_ep, keys), "/bench/reconstructor",
                                    CONTACT))
            load = _python(me, "_load", mode, unit, "", str(n), str(rate), str(out),
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
            helpers.append(load)
            assert load.stdout is not None and load.stdout.readline().strip() == "ready"
            header_seq = True
        assert load.stdin is not None
        load.stdin.write("go\n")
        load.stdin.flush()
        t_recv = _sink(sink, n, header_seq, timeout_s=30.0 + 2 * duration_s)
        load.wait(60)
        t_send = np.load(out)
    finally:
        sink.close()
        context.term()
        for proc in reversed(helpers):
            if proc.stdin is not None:
                proc.stdin.close()
                try:  # the proxy ends by itself when its stdin closes: no SIGINT mid-stop
                    proc.wait(2)
                except subprocess.TimeoutExpired:
                    pass
            if proc.poll() is None:
                proc.send_signal(2)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
    ok = np.isfinite(t_recv)
    latency = t_recv - t_send
    first = latency[::per_tick]
    send_s = float(t_send[-1] - t_send[0]) if n > 1 else 0.0
    backlog = float(np.nanmax(t_recv) - t_send[-1]) if ok.any() else np.inf
    return Run(mode, unit, rate, n, int(ok.sum()), latency[ok], first[np.isfinite(first)],
               send_s, backlog)


def _pooled_p99(runs: list[Run]) -> float:
    """p99 of the latencies of all ``runs`` together, us."""
    return float(np.percentile(np.concatenate([r.latency_s for r in runs]), 99)) * 1e6


def _table(runs: list[Run], unit: str, rates: list[float], repeats: int) -> None:
    """Medians over the repeats per rate and mode; ratios are medians of per-repeat ratios."""
    what = "wrench published -> its ContactPoint" if unit == "wrench" else (
        "WhiskerWrenchArray of a tick published -> its ContactPointArray")
    print(f"\nper {unit} ({what}); {repeats} run(s) each, medians")
    header = (f"{'rate/s':>8} {'mode':>9} {'sent':>7} {'lost':>6} {'p50 us':>9} {'p99 us':>9} "
              f"{'max us':>9} {'first p50':>9} {'backlog ms':>10} {'sustained':>9} {'p50 x':>7} "
              f"{'p99 x':>7} {'pooled p99 x':>12}")
    print(header)
    print("-" * len(header))
    for rate in rates:
        by_mode = {mode: [r for r in runs if (r.unit, r.rate, r.mode) == (unit, rate, mode)]
                   for mode in MODES}
        for mode, mine in by_mode.items():
            pairs = list(zip(mine, by_mode["bare"], strict=True))
            print(f"{rate:8.0f} {mode:>9} {mine[0].sent:7d} {max(r.lost for r in mine):6d} "
                  f"{np.median([r.pct(50) for r in mine]):9.0f} "
                  f"{np.median([r.pct(99) for r in mine]):9.0f} "
                  f"{np.median([r.pct(100) for r in mine]):9.0f} "
                  f"{np.median([r.pct(50, first=True) for r in mine]):9.0f} "
                  f"{np.median([r.backlog_s for r in mine]) * 1e3:10.1f} "
                  f"{sum(r.sustained for r in mine):>7d}/{len(mine)} "
                  f"{np.median([a.pct(50) / b.pct(50) for a, b in pairs]):7.1f} "
                  f"{np.median([a.pct(99) / b.pct(99) for a, b in pairs]):7.1f} "
                  f"{_pooled_p99(mine) / _pooled_p99(by_mode['bare']):12.1f}")
    for mode in MODES:
        ok = [rate for rate in rates if all(
            r.sustained for r in runs if (r.unit, r.rate, r.mode) == (unit, rate, mode))]
        best = f"{max(ok):.0f} wrenches/s" if ok else "none of the rates tried"
        print(f"highest rate sustained with zero loss in every run, per {unit} ({mode}): {best}")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "_proxy":
        _proxy()
        return 0
    if argv and argv[0] == "_load":
        _load(argv[1], argv[2], argv[3], int(argv[4]), float(argv[5]), argv[6])
        return 0
    if argv and argv[0] == "_echo":
        _echo(argv[1], argv[2], argv[3] == "proxy")
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=2.0, help="seconds per run")
    parser.add_argument("--rates", default="1000,4000,8000,16000,32000,64000",
                        help="aggregate wrenches/s to try (32 whiskers per tick)")
    parser.add_argument("--repeat", type=int, default=1, help="runs per rate, mode and unit")
    parser.add_argument("--units", default=",".join(UNITS),
                        help="what one message carries: wrench, tick or both")
    args = parser.parse_args(argv)
    rates = [float(r) for r in args.rates.split(",")]
    units = [u for u in args.units.split(",") if u]
    if not units or set(units) - set(UNITS):
        parser.error(f"--units: choose from {', '.join(UNITS)}")
    print(f"{os.cpu_count()} CPUs; {WHISKERS} whiskers per tick; {args.duration:g} s per run",
          flush=True)
    runs: list[Run] = []
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeat):
            for rate in rates:
                for unit in units:
                    for mode in MODES:
                        run = measure(mode, unit, rate, args.duration, Path(tmp))
                        runs.append(run)
                        print(f"  {repeat} {unit:6s} {mode:8s} {rate:8.0f}/s  p50 "
                              f"{run.pct(50):9.0f} us  p99 {run.pct(99):9.0f} us  first p50 "
                              f"{run.pct(50, first=True):9.0f} us  lost {run.lost}  backlog "
                              f"{run.backlog_s * 1e3:.1f} ms", flush=True)
    for unit in units:
        _table(runs, unit, rates, args.repeat)
    for unit in units:
        for mode in ("vibrissa", "curve"):
            target = [r for r in runs if (r.unit, r.rate, r.mode) == (unit, 32000, mode)]
            if target:
                lost = max(r.lost for r in target)
                sustained = sum(r.sustained for r in target)
                print(f"32 whiskers x 1 kHz, per {unit} ({mode}): "
                      f"{'zero loss' if lost == 0 else f'LOST {lost}'}, sustained in "
                      f"{sustained}/{len(target)} runs, pooled p99 {_pooled_p99(target):.0f} us")
        plain = [r for r in runs if (r.unit, r.mode) == (unit, "vibrissa")]
        curve = [r for r in runs if (r.unit, r.mode) == (unit, "curve")]
        if plain and curve:
            pairs = list(zip(curve, plain, strict=True))
            print(f"CURVE overhead per {unit}: p50 x{np.median([a.pct(50) / b.pct(50) for a, b in pairs]):.2f}, "
                  f"p99 x{np.median([a.pct(99) / b.pct(99) for a, b in pairs]):.2f} "
                  "(median over rates and repeats of curve / vibrissa)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
