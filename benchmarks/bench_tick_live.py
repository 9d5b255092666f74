"""Where a live tick's time goes in the reconstructor node: its steps, timed in the running node.

bench_pipeline.py's ``vibrissa`` chain per tick (32 whiskers at 1 kHz, one WhiskerWrenchArray
a tick: load -> reconstructor -> sink, real sockets), with the floor (``bare``) in the same
run; the reconstructor is the real node, started through this file, which notes the time
(wall, and the node thread's CPU time) at each step of each tick:

* ``decode``: the message's frames off the socket -> the subscriber hands it over (the
  transport's checks and counts, and the decode);
* ``batching``: -> Step 2 starts (draining what else is queued, the pose wait);
* ``step 2``: `vibrissa.streaming.reconstruct_messages` (with its counts);
* ``to publish``: -> the points' publish starts (the stream's counters);
* ``encode``, ``send``: the publish's encode and its three frames onto the socket.

Medians and 99th percentiles over the ticks of every run, us, and the chains' end-to-end p50 /
p99 (send by the load -> receipt by the sink). Wall above CPU time in a step is time the node's
thread was not running (another thread or process had the core). Not a test.

Usage: ``python benchmarks/bench_tick_live.py [--duration 8] [--repeat 3]``
"""

from __future__ import annotations

import argparse
import atexit
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import bench_pipeline as pipeline  # beside this file (as a script, its folder is on the path)
import msgpack
import numpy as np

STEPS = ("taken", "received", "step2_start", "step2_end", "publish", "encoded", "sent")
INTERVALS = ("decode", "batching", "step 2", "to publish", "encode", "send")
STEPS_ENV = "BENCH_TICK_STEPS"  # where the node writes its notes (an .npz)


def _node(argv: list[str]) -> int:
    """The reconstructor node, its steps noted per tick (by the tick's seq: the bench's load
    numbers its ticks from 0, as its publisher numbers its messages) into ``STEPS_ENV``."""
    from vibrissa.nodes import reconstructor
    from vibrissa.streaming import stream
    from vibrissa.wire import inbox, transport

    notes: dict[str, dict[int, tuple[float, float]]] = {step: {} for step in STEPS}
    prefix = pipeline.TOPIC.encode() + b"\0"

    def note(step: str, seq: int) -> None:
        notes[step][seq] = (time.perf_counter(), time.thread_time())

    def after(cls: Any, name: str, on_return: Callable[..., None]) -> None:
        original = getattr(cls, name)

        def noted(self: Any, *args: Any) -> Any:
            result = original(self, *args)
            on_return(result)
            return result
        setattr(cls, name, noted)

    def taken(took: Any) -> None:  # (frames, cut) or None
        if took is not None and took[0][0] == prefix:
            note("taken", msgpack.unpackb(took[0][1])["seq"])

    def received(rx: Any) -> None:
        if rx is not None and rx.topic == pipeline.TOPIC:
            note("received", rx.header.seq)

    after(inbox.Inbox, "take", taken)
    after(transport.Subscriber, "receive", received)
    step2 = stream.reconstruct_messages

    def reconstruct_messages(msgs: Any, *args: Any, **kwargs: Any) -> Any:
        for msg in msgs:
            note("step2_start", msg.seq)
        out = step2(msgs, *args, **kwargs)
        for msg in msgs:
            note("step2_end", msg.seq)
        return out
    stream.reconstruct_messages = reconstruct_messages
    encode, publish = transport.encode, transport.Publisher.publish

    def encode_noted(msg: Any) -> bytes:
        payload = encode(msg)
        if msg.TYPE_NAME == "vibrissa/ContactPointArray":
            note("encoded", msg.seq)
        return payload

    def publish_noted(self: Any, msg: Any) -> None:
        points = msg.TYPE_NAME == "vibrissa/ContactPointArray"
        if points:
            note("publish", msg.seq)
        publish(self, msg)
        if points:
            note("sent", msg.seq)
    transport.encode = encode_noted
    transport.Publisher.publish = publish_noted  # type: ignore[method-assign]

    def save() -> None:
        np.savez(os.environ[STEPS_ENV], **{
            step: np.array([(seq, *times) for seq, times in sorted(notes[step].items())],
                           dtype=float).reshape(-1, 3) for step in STEPS})
    atexit.register(save)
    return reconstructor.main(argv)


def _intervals(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each interval's wall and CPU time per tick that has every step, s."""
    notes = np.load(path)
    seqs = set.intersection(*(set(notes[step][:, 0].tolist()) for step in STEPS))
    times = {}
    for step in STEPS:
        rows = notes[step]
        keep = np.isin(rows[:, 0], sorted(seqs))
        times[step] = rows[keep][np.argsort(rows[keep][:, 0])]
    return {name: (times[b][:, 1] - times[a][:, 1], times[b][:, 2] - times[a][:, 2])
            for name, a, b in zip(INTERVALS, STEPS[:-1], STEPS[1:], strict=True)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=8.0, help="seconds per run")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each chain")
    args = parser.parse_args()
    pipeline.RECONSTRUCTOR = [str(Path(__file__).resolve()), "_node"]
    wall: dict[str, list[np.ndarray]] = {name: [] for name in INTERVALS}
    cpu: dict[str, list[np.ndarray]] = {name: [] for name in INTERVALS}
    latency: dict[str, list[np.ndarray]] = {"bare": [], "vibrissa": []}
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeat):
            for mode in ("bare", "vibrissa")[::-1 if repeat % 2 else 1]:
                steps = Path(tmp) / f"steps-{repeat}.npz"
                os.environ[STEPS_ENV] = str(steps)
                run = pipeline.measure(mode, "tick", 32000.0, args.duration, Path(tmp))
                latency[mode].append(run.latency_s)
                print(f"  {repeat} {mode:8s} p50 {run.pct(50):6.0f} us  p99 {run.pct(99):6.0f} us"
                      f"  lost {run.lost}  steal {run.steal * 100:.1f} %", flush=True)
                if mode == "vibrissa":
                    for name, (w, c) in _intervals(steps).items():
                        wall[name].append(w)
                        cpu[name].append(c)
    print("\nthe reconstructor's steps of a tick over every run's ticks, medians and 99th "
          "percentiles, us")
    print(f"{'step':>12} {'wall':>7} {'cpu':>7} {'wall p99':>9} {'cpu p99':>8}")

    def row(name: str, w: np.ndarray, c: np.ndarray) -> None:
        print(f"{name:>12} {np.median(w) * 1e6:7.1f} {np.median(c) * 1e6:7.1f} "
              f"{np.percentile(w, 99) * 1e6:9.1f} {np.percentile(c, 99) * 1e6:8.1f}")
    for name in INTERVALS:
        row(name, np.concatenate(wall[name]), np.concatenate(cpu[name]))
    row("in the node", sum(np.concatenate(wall[name]) for name in INTERVALS),
        sum(np.concatenate(cpu[name]) for name in INTERVALS))
    print("\nend to end, all runs together, us")
    for mode, runs in latency.items():
        both = np.concatenate(runs)
        print(f"{mode:>12} p50 {np.percentile(both, 50) * 1e6:6.0f}  "
              f"p99 {np.percentile(both, 99) * 1e6:6.0f}")


if __name__ == "__main__":
    if sys.argv[1:2] == ["_node"]:
        sys.exit(_node(sys.argv[2:]))
    main()
