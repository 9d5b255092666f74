"""A live tick's CPU in the reconstructor, socket-free: decode, Step 2 with its bookkeeping
(`vibrissa.streaming.reconstruct_messages`) and encode of one 32-whisker tick, in one process in
a loop (`time.thread_time_ns`, medians over ``--ticks`` ticks of bench_pipeline.py's
payloads: with clamp poses, and the robot's rows in their clamp frames without poses, whose
Step 2 needs a pose stream and is left out here).

Warm, and cold: ``--evict`` MB written before each tick, more than a core's L2 cache, so that
each tick finds its code and data evicted, as a live node does (it sleeps between ticks while
other processes run): what a tick costs live is closer to the cold figures than to the warm.

Usage: ``python benchmarks/bench_tick_cpu.py [--ticks 3000] [--evict 8]``
"""

from __future__ import annotations

import argparse
import time

import bench_pipeline as pipeline  # beside this file (as a script, its folder is on the path)
import numpy as np

from vibrissa.msgs.codec import decode, encode
from vibrissa.streaming.step2 import reconstruct_messages

WARM_UP = 200


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=3000)
    parser.add_argument("--evict", type=float, default=8.0,
                        help="MB written before each tick of the cold runs (0: warm only)")
    args = parser.parse_args()
    evict = np.ones(round(args.evict * 1e6 / 8))
    for robot, cold in ((False, False), (True, False), (False, True), (True, True)):
        if cold and not evict.size:
            continue
        payloads = pipeline._payloads(args.ticks + WARM_UP, "tick", robot, 1e-3)
        spent: dict[str, list[int]] = {"decode": [], "step2": [], "encode": []}
        for k, payload in enumerate(payloads):
            if cold:
                evict += 1.0
            t0 = time.thread_time_ns()
            msg = decode(payload)
            t1 = time.thread_time_ns()
            if robot:
                if k >= WARM_UP:
                    spent["decode"].append(t1 - t0)
                continue
            (done,) = reconstruct_messages([msg])
            t2 = time.thread_time_ns()
            encode(done.contacts)
            t3 = time.thread_time_ns()
            if k >= WARM_UP:
                for name, ns in (("decode", t1 - t0), ("step2", t2 - t1), ("encode", t3 - t2)):
                    spent[name].append(ns)
        kind = "robot rows (no poses)" if robot else "rows with clamp poses"
        print(f"{'cold' if cold else 'warm'}, {kind}: " + ", ".join(f"{name} {np.median(ns) / 1e3:.1f} us"
                                      for name, ns in spent.items() if ns))


if __name__ == "__main__":
    main()
