"""Latency and throughput of the node graph: wrench published -> contact point received.

Pipeline (every box its own process, real ZeroMQ on loopback)::

    load --/bench/wrench--> proxy --> reconstructor --/bench/contact--> proxy --> sink (here)

Floor, in the same run, with the same wrench payload and the same pacing::

    load (bare PUB) --> echo (SUB -> PUB, forwards the bytes) --> sink (bare SUB)

The load process sends ``whiskers`` samples per tick (one per whisker) at ``rate`` samples/s in
total, pre-encoded, and records the send time of each; the sink records the receive time of
each by sequence number (the transport header's ``seq``, so the sink decodes nothing). Loss
is sent - received (every benchmark wrench has a contact). A rate is *sustained* when nothing
is lost and the sink is done within ``max(50 ms, 5 %)`` of the send duration after the last
send (no backlog grows). ``first p50`` is the median latency of the first sample of each tick
(whisker 0), which waits for no other sample of its tick.

Run: ``python benchmarks/bench_pipeline.py [--duration 2] [--rates 1000,...]``. Not a test.
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

WHISKERS = 32
TOPIC = "/bench/wrench"
CONTACT = "/bench/contact"


# -- helper processes (python bench_pipeline.py _proxy | _load | _echo ...) ----------------------


def _payloads(n: int) -> list[bytes]:
    """``n`` encoded WhiskerWrench, seq 0..n-1, cycling over valid wrenches and whiskers."""
    from vibrissa.msgs import WhiskerWrench, encode

    from vibrissa.reconstruct import reconstruct

    rng = np.random.default_rng(1)
    p0, f0, m0 = rng.uniform(-1, 1, (512, 3)), rng.normal(size=(512, 3)), rng.normal(size=(512, 3))
    valid = np.flatnonzero(reconstruct(p0, f0, m0).valid)
    out = []
    for i in range(n):
        k = valid[i % len(valid)]
        out.append(encode(WhiskerWrench(
            stamp=0.0, seq=i, whisker_id=f"whisker{i % WHISKERS}", frame_id="world",
            clamp_position=p0[k], clamp_orientation=[0.0, 0.0, 0.0, 1.0], f0=f0[k], m0=m0[k])))
    return out


def _pace(send: Any, n: int, rate: float, t_send: np.ndarray) -> None:
    """Call ``send(i)`` for i < n in ticks of WHISKERS samples at ``rate`` samples/s."""
    tick = WHISKERS / rate
    t0 = time.perf_counter() + 0.05
    clock_offset = time.time() - time.perf_counter()
    for start in range(0, n, WHISKERS):
        due = t0 + (start // WHISKERS) * tick
        delay = due - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        for i in range(start, min(n, start + WHISKERS)):
            t_send[i] = time.perf_counter() + clock_offset
            send(i)


def _load(mode: str, endpoint: str, n: int, rate: float, out: str) -> None:
    payloads = _payloads(n)
    t_send = np.zeros(n)
    if mode == "bare":
        context: zmq.Context[Any] = zmq.Context()
        sock = context.socket(zmq.PUB)
        sock.setsockopt(zmq.SNDHWM, n + 10)
        sock.setsockopt(zmq.LINGER, 2000)
        sock.bind(endpoint)
        prefix = TOPIC.encode() + b"\0"
        print("ready", flush=True)
        sys.stdin.readline()  # the bench says go once the chain is connected

        def send_bare(i: int) -> None:
            sock.send_multipart((prefix, i.to_bytes(8, "little"), payloads[i]))

        _pace(send_bare, n, rate, t_send)
        sock.close()
        context.term()
    else:
        from vibrissa.msgs import WhiskerWrench
        from vibrissa.nodes.runtime import Node

        with Node("load", "/bench", handle_signals=False) as node:
            pub = node.create_publisher("wrench", WhiskerWrench, wait_for=["reconstructor"],
                                        hwm=n + 10)
            if not node.wait_for_subscribers("wrench", ["reconstructor"], 60.0):
                raise SystemExit("reconstructor not ready")
            print("ready", flush=True)
            sys.stdin.readline()
            _pace(lambda i: pub.publish_raw(payloads[i]), n, rate, t_send)
            pub.publish_end_of_stream(node.fqn)
    np.save(out, t_send)


def _echo(source: str, endpoint: str) -> None:
    context: zmq.Context[Any] = zmq.Context()
    sub, pub = context.socket(zmq.SUB), context.socket(zmq.PUB)
    for sock in (sub, pub):
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.RCVHWM, 1_000_000)
        sock.setsockopt(zmq.SNDHWM, 1_000_000)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    pub.bind(endpoint)
    sub.connect(source)
    try:
        while True:
            pub.send_multipart(sub.recv_multipart())
    except KeyboardInterrupt:
        pass
    finally:
        sub.close()
        pub.close()
        context.term()


def _proxy() -> None:
    from vibrissa.wire.transport import Endpoints, Proxy

    proxy = Proxy(Endpoints.free(), zmq.Context(), hwm=1_000_000)
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
    """One measured run."""

    mode: str
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
        """Percentile ``q`` of the latency, us (``first``: of the first sample of each tick)."""
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
        seq = (msgpack.unpackb(frames[1])["seq"] if header_seq
               else int.from_bytes(frames[1], "little"))
        if seq < n:
            t_recv[seq] = now
            got += 1
        idle_until = time.monotonic() + 5.0
    return t_recv


def measure(mode: str, rate: float, duration_s: float, tmp: Path) -> Run:
    """One run of the pipeline (``mode`` = ``vibrissa``) or the floor (``bare``)."""
    n = int(rate * duration_s)
    out = tmp / f"send-{mode}-{int(rate)}.npy"
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
            load = _python(me, "_load", "bare", load_ep, str(n), str(rate), str(out),
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE)
            helpers.append(load)
            assert load.stdout is not None and load.stdout.readline().strip() == "ready"
            helpers.append(_python(me, "_echo", load_ep, echo_ep))
            sink.setsockopt(zmq.SUBSCRIBE, b"")
            sink.connect(echo_ep)
            time.sleep(1.5)  # slow joiners: both subscriptions reach their publishers
            header_seq = False
        else:
            proxy = _python(me, "_proxy", stdin=subprocess.PIPE, stdout=subprocess.PIPE)
            helpers.append(proxy)
            assert proxy.stdout is not None
            pub_ep, sub_ep = proxy.stdout.readline().split()
            env = {**os.environ, "VIBRISSA_PUB_ENDPOINT": pub_ep,
                   "VIBRISSA_SUB_ENDPOINT": sub_ep, "VIBRISSA_LOG_LEVEL": "WARNING"}
            sink.setsockopt(zmq.SUBSCRIBE, CONTACT.encode() + b"\0")
            sink.connect(sub_ep)
            helpers.append(_python("-m", "vibrissa.nodes.reconstructor", "--name",
                                   "reconstructor", "--namespace", "/bench", env=env))
            load = _python(me, "_load", "vibrissa", "", str(n), str(rate), str(out),
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
    first = latency[::WHISKERS]
    send_s = float(t_send[-1] - t_send[0]) if n > 1 else 0.0
    backlog = float(np.nanmax(t_recv) - t_send[-1]) if ok.any() else np.inf
    return Run(mode, rate, n, int(ok.sum()), latency[ok], first[np.isfinite(first)], send_s,
               backlog)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "_proxy":
        _proxy()
        return 0
    if argv and argv[0] == "_load":
        _load(argv[1], argv[2], int(argv[3]), float(argv[4]), argv[5])
        return 0
    if argv and argv[0] == "_echo":
        _echo(argv[1], argv[2])
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=2.0, help="seconds per run")
    parser.add_argument("--rates", default="1000,4000,8000,16000,32000,64000",
                        help="aggregate samples/s to try (32 whiskers each)")
    args = parser.parse_args(argv)
    rates = [float(r) for r in args.rates.split(",")]
    print(f"{os.cpu_count()} CPUs; {WHISKERS} whiskers; {args.duration:g} s per run; "
          f"latency = wrench published -> contact received", flush=True)
    runs: list[Run] = []
    with tempfile.TemporaryDirectory() as tmp:
        for rate in rates:
            for mode in ("bare", "vibrissa"):
                run = measure(mode, rate, args.duration, Path(tmp))
                runs.append(run)
                print(f"  {mode:8s} {rate:8.0f}/s  p50 {run.pct(50):9.0f} us  p99 "
                      f"{run.pct(99):9.0f} us  first p50 {run.pct(50, first=True):9.0f} us  "
                      f"lost {run.lost}", flush=True)
    print()
    header = (f"{'rate/s':>8} {'mode':>9} {'sent':>7} {'lost':>6} {'p50 us':>9} {'p99 us':>9} "
              f"{'max us':>9} {'first p50':>9} {'backlog ms':>10} {'sustained':>9} {'p50 x':>7} "
              f"{'p99 x':>7}")
    print(header)
    print("-" * len(header))
    for rate in rates:
        bare = next(r for r in runs if r.rate == rate and r.mode == "bare")
        for run in (bare, next(r for r in runs if r.rate == rate and r.mode == "vibrissa")):
            ratio50 = run.pct(50) / bare.pct(50)
            ratio99 = run.pct(99) / bare.pct(99)
            print(f"{rate:8.0f} {run.mode:>9} {run.sent:7d} {run.lost:6d} {run.pct(50):9.0f} "
                  f"{run.pct(99):9.0f} {run.pct(100):9.0f} {run.pct(50, first=True):9.0f} "
                  f"{run.backlog_s * 1e3:10.1f} "
                  f"{'yes' if run.sustained else 'no':>9} {ratio50:7.1f} {ratio99:7.1f}")
    for mode in ("vibrissa", "bare"):
        ok = [r.rate for r in runs if r.mode == mode and r.sustained]
        best = f"{max(ok):.0f} samples/s" if ok else "none of the rates tried"
        print(f"highest sustained rate with zero loss ({mode}): {best}")
    target = [r for r in runs if r.rate == 32000 and r.mode == "vibrissa"]
    if target:
        verdict = "zero loss" if target[0].lost == 0 else f"LOST {target[0].lost}"
        print(f"32 whiskers x 1 kHz: {verdict}, "
              f"{'sustained' if target[0].sustained else 'NOT sustained (backlog grows)'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
