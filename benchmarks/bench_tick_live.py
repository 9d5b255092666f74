"""Where a live tick's time goes in the reconstructor node: its steps, timed in the running node.

bench_pipeline.py's ``vibrissa`` chain per tick (32 whiskers at 1 kHz, one WhiskerWrenchArray
a tick: load -> reconstructor -> sink, real sockets), with the floor (``bare``) in the same
run; the reconstructor is the real node, started through this file, which notes the time
(wall, and the node thread's CPU time) at each step of each tick:

* ``read``: the inbox's poll returns with the message ready -> its frames off the socket;
* ``decode``: -> the subscriber hands it over (the transport's checks and counts, and the
  decode);
* ``batching``: -> Step 2 starts (draining what else is queued, the pose wait);
* ``step 2``: `vibrissa.streaming.reconstruct_messages` (with its counts);
* ``to publish``: -> the points' publish starts (the stream's counters);
* ``encode``, ``send``: the publish's encode and its three frames onto the socket.

Medians and 99th percentiles over the ticks of every run, us, and the chains' end-to-end p50 /
p99 (send by the load -> receipt by the sink). Wall above CPU time in a step is time the node's
thread was not running (another thread or process had the core). Not a test.

``--bound`` runs a third chain, ``bound``: the same node with the codec's checks and Step 2's
bookkeeping taken out (`_bare_bones`: msgpack and array views in, the one compiled Step 2 call,
every row a point, msgpack out). It is no code path of the package, it gives wrong answers to
bad input, and it is the lower bound of a Python node on this transport: what the
checks and bookkeeping cost a live tick is the ``vibrissa`` chain's latency above it.

Usage: ``python benchmarks/bench_tick_live.py [--duration 8] [--repeat 3] [--bound]``
"""

from __future__ import annotations

import argparse
import atexit
import gc
import math
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

STEPS = ("woken", "taken", "received", "step2_start", "step2_end", "publish", "encoded", "sent")
INTERVALS = ("read", "decode", "batching", "step 2", "to publish", "encode", "send")
STEPS_ENV = "BENCH_TICK_STEPS"  # where the node writes its notes (an .npz)
BOUND_ENV = "BENCH_TICK_BOUND"  # set: the node runs `_bare_bones`


def _node(argv: list[str]) -> int:
    """The reconstructor node, its steps noted per tick (by the tick's seq: the bench's load
    numbers its ticks from 0, as its publisher numbers its messages) into ``STEPS_ENV``."""
    from vibrissa.nodes import reconstructor
    from vibrissa.streaming import stream
    from vibrissa.wire import inbox, transport

    notes: dict[str, dict[int, tuple[float, float]]] = {step: {} for step in STEPS}
    # the notes are the one thing here that grows tick by tick: without this, the collections
    # they cause stall the node for tens of ms every few seconds (a p99 of 40-60 ms; the node
    # itself leaves nothing to collect: 3 ms in bench_pipeline.py's 8 s runs)
    gc.disable()
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

    woken = [(math.nan, math.nan)]  # when the inbox's poll last returned with a socket ready

    def ready(sockets: Any) -> None:
        if sockets:
            woken[0] = (time.perf_counter(), time.thread_time())

    def taken(took: Any) -> None:  # (frames, cut) or None
        if took is not None and took[0][0] == prefix:
            seq = msgpack.unpackb(took[0][1])["seq"]
            note("taken", seq)
            notes["woken"][seq] = woken[0]

    def received(rx: Any) -> None:
        if rx is not None and rx.topic == pipeline.TOPIC:
            note("received", rx.header.seq)

    after(inbox.Inbox, "_ready", ready)
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
    if os.environ.get(BOUND_ENV):
        decode_bare, step2, encode = _bare_bones(transport.decode, step2, encode)
        transport.decode = decode_bare
    return reconstructor.main(argv)


def _bare_bones(decode: Callable[..., Any], step2: Callable[..., Any], encode: Callable[..., Any]
                ) -> tuple[Callable[..., Any], Callable[..., Any], Callable[..., Any]]:
    """``decode``, Step 2 (`reconstruct_messages`) and ``encode`` of a tick cut to the bone
    (the ``bound`` chain): a WhiskerWrenchArray payload is unpacked into views of its arrays
    with no check, a tick of clamp poses and the bench's one rod is one call of the compiled
    Step 2 with every row its point, and a ContactPointArray is packed as it is (the bench's
    sink only times it). Anything else goes the package's way."""
    from vibrissa.msgs import ContactPointArray, WhiskerWrenchArray
    from vibrissa.reconstruct_rods import rows_si
    from vibrissa.streaming.step2 import Reconstructed
    from vibrissa.units import RodScale, rod_units

    # the kernel's arguments after the tick's arrays: the bench's rod (the node's default),
    # no noise model, every row straight and uniform (`vibrissa.reconstruct.reconstruct_si`)
    uniform = (rod_units([RodScale()]), np.empty((0, 6, 6)), 3.0, np.empty((0, 3)), np.empty(0),
               np.empty(0, dtype=np.bool_), np.empty(0, dtype=np.int64))
    # compiled for read-only views (as decoded) before the first tick
    q, p, f0, m0 = np.array([[0.0, 0.0, 0.0, 1.0]]), np.zeros((1, 3)), np.ones((1, 3)), np.ones((1, 3))
    for array in (q, p, f0, m0):
        array.flags.writeable = False
    rows_si(q, p, f0, m0, *uniform)

    def decode_bare(payload: bytes, expected: Any = None) -> Any:
        obj = msgpack.unpackb(payload)
        if obj["_type"] != WhiskerWrenchArray.TYPE_NAME:
            return decode(payload, expected)
        arrays = {name: np.frombuffer(obj[name]["data"]).reshape(obj[name]["shape"])
                  for name in ("f0", "m0", "clamp_position", "clamp_orientation")}
        return WhiskerWrenchArray.unchecked(
            stamp=obj["stamp"], seq=obj["seq"], whisker_ids=obj["whisker_ids"],
            frame_ids=obj["frame_ids"], pose_frame_id=obj["pose_frame_id"], **arrays)

    def step2_bare(msgs: Any, *args: Any, **kwargs: Any) -> Any:
        if len(msgs) != 1:
            return step2(msgs, *args, **kwargs)
        msg = msgs[0]
        n = len(msg.whisker_ids)
        floats, ints, _ = rows_si(msg.clamp_orientation, msg.clamp_position, msg.f0, msg.m0,
                               *uniform)
        contacts = ContactPointArray.unchecked(
            stamp=msg.stamp, seq=msg.seq, frame_id=msg.pose_frame_id,
            whisker_ids=msg.whisker_ids, point=floats[:3 * n].reshape(n, 3),
            s1=floats[6 * n:7 * n], phase=ints[:n], force=floats[3 * n:6 * n].reshape(n, 3),
            status=ints[n:2 * n], covariance=None, free_ids=[])
        return [Reconstructed(contacts, no_contact=0, bad_pose=0)]

    def encode_bare(msg: Any) -> bytes:
        if msg.TYPE_NAME != ContactPointArray.TYPE_NAME:
            return encode(msg)  # type: ignore[no-any-return]
        out = {"_type": msg.TYPE_NAME, "_v": msg.VERSION, "stamp": msg.stamp, "seq": msg.seq,
               "frame_id": msg.frame_id, "whisker_ids": msg.whisker_ids, "free_ids": []}
        for name in ("point", "s1", "phase", "force", "status"):
            value = getattr(msg, name)
            out[name] = {"dtype": value.dtype.str, "shape": value.shape, "data": value.tobytes()}
        return msgpack.packb(out)  # type: ignore[no-any-return]

    return decode_bare, step2_bare, encode_bare


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
    parser.add_argument("--bound", action="store_true",
                        help="also the node cut to the bone (the `bound` chain)")
    args = parser.parse_args()
    pipeline.RECONSTRUCTOR = [str(Path(__file__).resolve()), "_node"]
    chains = ("bare", "vibrissa", "bound") if args.bound else ("bare", "vibrissa")
    nodes = chains[1:]
    wall: dict[str, dict[str, list[np.ndarray]]] = {
        node: {name: [] for name in INTERVALS} for node in nodes}
    cpu: dict[str, dict[str, list[np.ndarray]]] = {
        node: {name: [] for name in INTERVALS} for node in nodes}
    latency: dict[str, list[np.ndarray]] = {chain: [] for chain in chains}
    # each run's p50 and p99 over the floor's of the same repeat
    ratios: dict[str, list[np.ndarray]] = {node: [] for node in nodes}
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeat):
            floor = np.full(2, math.nan)
            for chain in chains[::-1 if repeat % 2 else 1]:
                steps = Path(tmp) / f"steps-{chain}-{repeat}.npz"
                os.environ[STEPS_ENV] = str(steps)
                os.environ.pop(BOUND_ENV, None)
                if chain == "bound":
                    os.environ[BOUND_ENV] = "1"
                run = pipeline.measure("bare" if chain == "bare" else "vibrissa", "tick",
                                       32000.0, args.duration, Path(tmp))
                latency[chain].append(run.latency_s)
                print(f"  {repeat} {chain:8s} p50 {run.pct(50):6.0f} us  p99 {run.pct(99):6.0f} "
                      f"us  lost {run.lost}  steal {run.steal * 100:.1f} %", flush=True)
                if chain == "bare":
                    floor = np.array([run.pct(50), run.pct(99)])
                else:
                    ratios[chain].append(np.array([run.pct(50), run.pct(99)]))
                    for name, (w, c) in _intervals(steps).items():
                        wall[chain][name].append(w)
                        cpu[chain][name].append(c)
            for node in nodes:
                ratios[node][-1] /= floor
    os.environ.pop(BOUND_ENV, None)

    def row(name: str, w: np.ndarray, c: np.ndarray) -> None:
        print(f"{name:>12} {np.median(w) * 1e6:7.1f} {np.median(c) * 1e6:7.1f} "
              f"{np.percentile(w, 99) * 1e6:9.1f} {np.percentile(c, 99) * 1e6:8.1f}")
    for node in nodes:
        print(f"\nthe reconstructor's steps of a tick ({node}) over every run's ticks, medians and "
              "99th percentiles, us")
        print(f"{'step':>12} {'wall':>7} {'cpu':>7} {'wall p99':>9} {'cpu p99':>8}")
        for name in INTERVALS:
            row(name, np.concatenate(wall[node][name]), np.concatenate(cpu[node][name]))
        row("in the node", sum(np.concatenate(wall[node][name]) for name in INTERVALS),
            sum(np.concatenate(cpu[node][name]) for name in INTERVALS))
    print("\nend to end, all runs together, us; over the floor: the median of each run's p50 and "
          "p99 over the floor's of the same repeat")
    for chain, runs in latency.items():
        both = np.concatenate(runs)
        over = ""
        if chain in ratios:
            p50, p99 = np.median(ratios[chain], axis=0)
            over = f"  {p50:.2f}x / {p99:.2f}x the floor"
        print(f"{chain:>12} p50 {np.percentile(both, 50) * 1e6:6.0f}  "
              f"p99 {np.percentile(both, 99) * 1e6:6.0f}{over}")


if __name__ == "__main__":
    if sys.argv[1:2] == ["_node"]:
        sys.exit(_node(sys.argv[2:]))
    main()
