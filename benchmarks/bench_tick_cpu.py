"""A live tick's CPU in the reconstructor, socket-free: decode, Step 2 with its bookkeeping
(`vibrissa.streaming.Step2Stream`) and encode of one 32-whisker tick, in one process in a loop
(`time.thread_time_ns`, medians over ``--ticks`` ticks of bench_pipeline.py's payloads: with
clamp poses, and the robot's rows in their clamp frames, placed through bench_pipeline.py's
robot description and its pose stream, a pose every 10 ticks one pose period ahead).

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

from vibrissa.msgs import RobotPose
from vibrissa.msgs.codec import decode, encode
from vibrissa.streaming import Step2Stream, StreamSettings

WARM_UP = 200


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=3000)
    parser.add_argument("--evict", type=float, default=8.0,
                        help="MB written before each tick of the cold runs (0: warm only)")
    args = parser.parse_args()
    evict = np.ones(round(args.evict * 1e6 / 8))
    tick_s = 1e-3
    poses = [decode(p) for p in pipeline._poses(args.ticks + WARM_UP, tick_s, 0.0)[0]]
    for cold in (False, True) if evict.size else (False,):
        for robot in (False, True):
            payloads = pipeline._payloads(args.ticks + WARM_UP, "tick", robot, tick_s)
            stream = Step2Stream(StreamSettings(whiskers=pipeline._robot() if robot else ()))
            ahead = iter(poses)
            spent: dict[str, list[int]] = {"decode": [], "step2": [], "encode": []}
            for k, payload in enumerate(payloads):
                if robot and k % round(pipeline.POSE_PERIOD_S / tick_s) == 0:
                    for _ in range(2 if k == 0 else 1):  # the pose one period ahead too
                        pose = next(ahead)
                        assert isinstance(pose, RobotPose)
                        stream.add_pose(pose)
                if cold:
                    evict += 1.0
                t0 = time.thread_time_ns()
                msg = decode(payload)
                t1 = time.thread_time_ns()
                stream.add_wrenches([msg])
                (done,) = stream.take()
                t2 = time.thread_time_ns()
                encode(done.contacts)
                t3 = time.thread_time_ns()
                stream.apply_poses()
                assert len(done.contacts.whisker_ids) == len(msg.whisker_ids)
                if k >= WARM_UP:
                    for name, ns in (("decode", t1 - t0), ("step2", t2 - t1), ("encode", t3 - t2)):
                        spent[name].append(ns)
            kind = "robot rows (poses in a stream)" if robot else "rows with clamp poses"
            print(f"{'cold' if cold else 'warm'}, {kind}: " + ", ".join(
                f"{name} {np.median(ns) / 1e3:.1f} us" for name, ns in spent.items()))


if __name__ == "__main__":
    main()
