"""Net F/T driver at the sensor's top rate: the simulated device (its own process) streams 7 kHz
over loopback UDP; the driver node (its own process) publishes every record as a WhiskerWrenchArray of one row;
a subscriber here counts them. Baseline in the same run: a bare UDP receive loop on the same
device. Loss is "unexplained" when the device made a record that the driver neither took
nor counted (lost, reordered); of the records it took, the stale ones (too old behind the
newest) are counted and not published.

    .venv/bin/python benchmarks/bench_netft.py [--rate 7000] [--seconds 5]
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml
import zmq

from vibrissa.msgs import NodeStatus, WhiskerWrenchArray
from vibrissa.wire import STATUS_TOPIC, Endpoints, Proxy, Subscriber
from vibrissa.wire.netft import Command, StreamTracker, pack_request

DEVICE = """
import sys, time, numpy as np
from vibrissa.wire.netft_device import NetFTDevice
rows = np.zeros((7000, 6)); rows[:, 0] = np.sin(np.arange(7000) / 100.0) * 0.1
with NetFTDevice(rows, rate_hz=float(sys.argv[1]), loop=True, port=int(sys.argv[2])) as d:
    print(d.address[1], flush=True)
    sys.stdin.readline()
    print(d.stats.made, flush=True)
"""


def start_device(rate: float) -> tuple[subprocess.Popen[str], int]:
    proc = subprocess.Popen([sys.executable, "-c", DEVICE, str(rate), "0"], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    return proc, int(proc.stdout.readline())


def stop_device(proc: subprocess.Popen[str]) -> int:
    assert proc.stdin is not None and proc.stdout is not None
    proc.stdin.write("\n")
    proc.stdin.flush()
    made = int(proc.stdout.readline())
    proc.wait(5)
    return made


def bare_loop(rate: float, seconds: float) -> dict[str, float]:
    """The baseline: recvfrom and the tracker's books, nothing published."""
    proc, port = start_device(rate)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    sock.settimeout(0.5)
    tracker = StreamTracker(ft_rate_hz=rate)
    sock.sendto(pack_request(Command.REALTIME), ("127.0.0.1", port))
    start = time.monotonic()
    while time.monotonic() - start < seconds:
        tracker.feed(sock.recv(65536), time.time())
    sock.sendto(pack_request(Command.STOP), ("127.0.0.1", port))
    sock.settimeout(0.2)
    try:  # what was sent before the stop arrived, as the driver takes it too
        while True:
            tracker.feed(sock.recv(65536), time.time())
    except TimeoutError:
        pass
    made = stop_device(proc)
    sock.close()
    c = tracker.counters
    return {"made": made, "delivered": c["received"], "lost": c["lost"], "stale": 0,
            "unexplained": made - c["received"] - c["lost"] - c["reordered"]}


def driver_run(rate: float, seconds: float) -> dict[str, float]:
    context: zmq.Context[object] = zmq.Context()
    with Proxy(Endpoints.free(), context=context) as proxy, tempfile.TemporaryDirectory() as tmp:
        assert proxy.endpoints is not None
        proc, port = start_device(rate)
        params = Path(tmp) / "netft.yaml"
        params.write_text(yaml.safe_dump({"whisker": "w0", "address": "127.0.0.1", "port": port,
                                          "ft_rate_hz": rate}))
        wrenches = Subscriber({"/w0/wrench": WhiskerWrenchArray}, proxy.endpoints, context)
        status = Subscriber({STATUS_TOPIC: NodeStatus}, proxy.endpoints, context)
        node = subprocess.Popen([sys.executable, "-m", "vibrissa.nodes.netft", "--name", "netft",
                                 "--namespace", "/w0", "--params-file", str(params)],
                                env={**os.environ, **proxy.endpoints.to_env()})
        got = 0
        start = None
        while True:
            rx = wrenches.receive(0.5)
            if rx is None:
                if start is not None and time.monotonic() - start > seconds:
                    break
                continue
            if start is None:
                start = time.monotonic()
            got += 1
            if time.monotonic() - start > seconds:
                break
        node.terminate()
        node.wait(10)
        made = stop_device(proc)
        counters: dict[str, int] = {}
        deadline = time.monotonic() + 2
        while time.monotonic() < deadline:
            s = status.receive(0.1)
            if s is not None and isinstance(s.msg, NodeStatus) and s.msg.node == "/w0/netft":
                counters = dict(s.msg.counters)
        wrenches.close()
        status.close()
    context.destroy(linger=0)
    records = counters.get("records", 0)
    return {"made": made, "delivered": got, "driver_records": records,
            "lost": counters.get("records_lost", 0), "stale": counters.get("stale", 0),
            "reordered": counters.get("reordered", 0), "zmq_lost": counters.get("lost", 0),
            "published": counters.get("published", 0),
            # stale records were taken (in ``records``), counted, and deliberately not published
            "unexplained": made - records - counters.get("records_lost", 0) - counters.get("reordered", 0)}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--rate", type=float, default=7000.0)
    parser.add_argument("--seconds", type=float, default=5.0)
    args = parser.parse_args()
    base = bare_loop(args.rate, args.seconds)
    run = driver_run(args.rate, args.seconds)
    print(f"Net F/T at {args.rate:g} Hz for {args.seconds:g} s, loopback UDP, device in its own process")
    print(f"{'path':<44} {'made':>8} {'taken':>8} {'lost':>6} {'stale':>6} {'unexpl.':>8}")
    print(f"{'bare UDP loop + books (baseline)':<44} {base['made']:>8} {base['delivered']:>8} "
          f"{base['lost']:>6} {0:>6} {base['unexplained']:>8}")
    print(f"{'driver node (records it took)':<44} {run['made']:>8} {run['driver_records']:>8} "
          f"{run['lost']:>6} {run['stale']:>6} {run['unexplained']:>8}")
    print(f"driver published {run['published']}, reordered {run['reordered']}; a subscriber got "
          f"{run['delivered']} in {args.seconds:g} s ({run['delivered'] / args.seconds:.0f} per s)")


if __name__ == "__main__":
    main()
