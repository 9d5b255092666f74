"""Live map delay benchmark: from a contact to the first published mesh that includes it.

Runs ``vibrissa launch launch/robot.yaml out:=TMP rate:=500 passes:=2`` (the robot demo at its
500 path samples/s, forth and back: 3 398 samples, about 7 s of stream after the source's
simulation; its own ZeroMQ domain, ``--domain``) and subscribes, as a tool does, to the
reconstructor's contacts (``/robot/contact``, ContactPointArray), the mapper's known mesh
(``/surface_mesh``, SurfaceMesh) and its cloud (``/contact_cloud``, ContactCloud). The mapper
stamps every message of an update with the newest stamp of the points it holds, so a mesh
stamped >= a contact's stamp holds that contact (its points, or, merged as repeats, the points
they repeat). For each contact message with at least one point:

    delay = (this benchmark received the first mesh stamped >= the contact's stamp)
            - (this benchmark received the contact)

both on this benchmark's time.monotonic(). Not the stamp against the wall clock: the stamps are
path time from ``epoch`` (the launch's start), and the source plays the path only after its
simulation, seconds later, so stamp-vs-wall would add that start-up lag to every delay. The
contact reaches this benchmark and the mapper alike (both subscribe to the reconstructor), so
the delay is the mapper's: the wait for an update, the update, its publication.

Every contact a mesh covers counts, the final map's too (its mesh, the last one, published
after every source's EndOfStream): ``final`` is how many only the final map covers (not a live
update; ``live p95`` leaves them out), ``never`` how many no mesh covers (every point of the
contact and of all later ones merged as a repeat, so no stamp at or after theirs was kept).

Reference, per contact: ``next update``, the delay to the next ContactCloud this benchmark
receives, whatever its stamp: the mapper's next publication after the contact, which is the
delay a mapper whose every update took no time would give (at a period P: uniform in [0, P],
p95 = 0.95 P). The mesh's delay exceeds it when the next publication is of an update begun
before the contact came (it waits for the one after); so the mesh's p95 over the reference's says
what the updates' length adds to their cadence, and ``p95 / P`` is the target's figure (<= 2; P =
``map_period_s``, 1 s by default). ``1st mesh`` is from the first contact to the first mesh,
``1st fit s`` how long the mapper's first update took and ``final s`` its last fit, the final
map's (its log's "mapped ... in X s"; the per-run lines list every fit, "after" the ones that
ended after the last contact).

Configurations: ``alone``, the launch by itself; ``loaded``, the same launch while a
32-whisker x 1 kHz stream (32 000 wrenches/s, a WhiskerWrenchArray of 32 rows per tick, poses
at 100 Hz) runs through its own reconstructor in its own graph: bench_pipeline.py's robot mode
(its proxy, its robot of 32 whiskers, its payloads and pacing; the payloads of 2 000 ticks sent
again and again with their stamps moved on), from the source's "simulated" log line (the stream
starts right after) until the launch ended (``--load-s`` at most). Each loaded run prints
whether that stream went on from the first contact to the final mesh and how many of its rows
its reconstructor placed. With ``--repeat`` the configurations alternate (their order reversed
every other repeat); the table holds the medians over the repeats of each run's figures, and the
total counts. The load average (1 min) at each run's end is printed. Not a test.

Usage: ``python benchmarks/bench_map_delay.py [--repeat 3] [--passes 2] [--rate 500]
[--configs alone,loaded] [--load-s 20] [--domain N]``
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import bench_pipeline as pipeline
import numpy as np
from bench_map_memory import launch

from vibrissa.msgs import ContactCloud, ContactPointArray, EndOfStream, SurfaceMesh
from vibrissa.nodes.mapper import MapperParams
from vibrissa.wire import Endpoints, Subscriber

CONTACT, MESH, CLOUD = "/robot/contact", "/surface_mesh", "/contact_cloud"
CONFIGS = ("alone", "loaded")
PERIOD_S = MapperParams.map_period_s
SIMULATED = re.compile(r"wrench_source\].*simulated \d+ whisker")
UPDATE = re.compile(r"\[mapper\].*mapped \S+: \d+ points .* in ([0-9.]+) s")
LOAD_RATE = 32_000.0  # wrenches/s: 32 whiskers x 1 kHz, per tick


@dataclass
class Delays:
    """The delays of one run's covered contacts, s, in the order received."""

    delay: np.ndarray  # to the first mesh stamped at or after the contact
    final_only: np.ndarray  # bool: that mesh is the final map's
    never: int  # contacts no mesh is stamped at or after
    next_update: np.ndarray  # to the next ContactCloud, whatever its stamp

    @property
    def live(self) -> np.ndarray:
        """The delays of the contacts covered by an update while the stream went on."""
        return self.delay[~self.final_only]


def delays(contacts: np.ndarray, meshes: np.ndarray, clouds: np.ndarray, final: bool) -> Delays:
    """The delays of ``contacts`` (K, 2: receive time, stamp) to the first of ``meshes`` (M, 2:
    receive time, stamp; in the order received) stamped at or after each, and to the next of
    ``clouds`` (receive times, ascending) received after each. ``final``: the last mesh is the
    final map's (its topic's EndOfStream came)."""
    contacts, meshes = np.reshape(contacts, (-1, 2)), np.reshape(meshes, (-1, 2))
    covering = np.searchsorted(np.maximum.accumulate(meshes[:, 1]), contacts[:, 1], side="left")
    seen = covering < len(meshes)
    t_seen = contacts[seen, 0]
    following = np.minimum(np.searchsorted(clouds, t_seen, side="right"), len(clouds) - 1)
    return Delays(meshes[covering[seen], 0] - t_seen,
                  covering[seen] == len(meshes) - 1 if final else np.zeros(len(t_seen), bool),
                  int(np.count_nonzero(~seen)),
                  np.asarray(clouds)[following] - t_seen if len(clouds) else np.zeros(0))


@dataclass
class Run:
    """One run of a configuration."""

    config: str
    delays: Delays
    updates: list[tuple[float, bool]]  # the mapper's fits (duration s, done during the stream)
    first_mesh_s: float  # from the first contact to the first mesh, s
    load: float  # load average (1 min) at the end
    mesh_lost: int  # meshes this benchmark missed (seq gaps)
    load_covered: bool | None = None  # the 32-whisker stream ran from the first contact on
    rows: tuple[int, int] = (0, 0)  # its rows placed, sent
    notes: list[str] = field(default_factory=list)


class Output:
    """A process's output lines with their arrival times (time.monotonic())."""

    def __init__(self, proc: subprocess.Popen[bytes]) -> None:
        self.lines: list[tuple[float, str]] = []
        assert proc.stdout is not None
        self._reader = threading.Thread(target=self._pump, args=(proc.stdout,), daemon=True)
        self._reader.start()

    def _pump(self, pipe: Any) -> None:
        for line in pipe:
            self.lines.append((time.monotonic(), line.decode(errors="replace")))

    def first(self, pattern: re.Pattern[str]) -> float | None:
        """When the first line matching ``pattern`` came, or None."""
        return next((t for t, line in list(self.lines) if pattern.search(line)), None)

    def text(self) -> str:
        return "".join(line for _, line in self.lines)


class Background:
    """The 32-whisker x 1 kHz robot stream of bench_pipeline.py through its own graph (proxy,
    reconstructor, load), ready to go."""

    def __init__(self, tmp: Path, load_s: float) -> None:
        me = str(Path(pipeline.__file__).resolve())  # its proxy
        env = {k: v for k, v in os.environ.items() if not k.startswith("VIBRISSA_")}
        env["VIBRISSA_LOG_LEVEL"] = "WARNING"
        self.helpers: list[subprocess.Popen[str]] = []
        proxy = pipeline._python(me, "_proxy", stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                 env=env)
        self.helpers.append(proxy)
        assert proxy.stdout is not None
        pub_ep, sub_ep = proxy.stdout.readline().split()
        env.update({"VIBRISSA_PUB_ENDPOINT": pub_ep, "VIBRISSA_SUB_ENDPOINT": sub_ep})
        self.endpoints = Endpoints(pub_ep, sub_ep)
        pipeline._write_robot(tmp / "robot32.yaml")
        self.helpers.append(pipeline._python(
            "-m", "vibrissa.nodes.reconstructor", "--name", "reconstructor", "--namespace",
            "/bench", "--param", f"robot:={tmp / 'robot32.yaml'}", "--param",
            f"pose_topic:={pipeline.POSE_TOPIC}", env=env))
        self.load = pipeline._python(str(Path(__file__).resolve()), "_load",
                                     str(int(LOAD_RATE * load_s) // pipeline.WHISKERS),
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
        self.helpers.append(self.load)
        assert self.load.stdout is not None and self.load.stdout.readline().strip() == "ready"
        self.started: float | None = None

    def go(self) -> None:
        assert self.load.stdin is not None
        self.load.stdin.write("go\n")
        self.load.stdin.flush()
        self.started = time.monotonic()

    def stop(self) -> tuple[int, int]:
        """End the stream (the load stops when its stdin closes) and its graph; the rows its
        reconstructor placed (``contacts``) and the rows sent."""
        assert self.load.stdin is not None and self.load.stdout is not None
        self.load.stdin.close()
        line = self.load.stdout.readline()  # "sent N", nothing if it failed
        sent = int(line.split()[-1]) * pipeline.WHISKERS if line.startswith("sent") else 0
        status = pipeline._node_status(self.endpoints, "/bench/reconstructor",
                                       lambda s: s.counters.get("contacts", 0) >= sent, 5.0)
        self.close()
        return status.counters.get("contacts", 0), sent

    def close(self) -> None:
        """Stop every process, as bench_pipeline.measure does."""
        for proc in reversed(self.helpers):
            if proc.stdin is not None and not proc.stdin.closed:
                proc.stdin.close()
                try:
                    proc.wait(2)
                except subprocess.TimeoutExpired:
                    pass
            if proc.poll() is None:
                proc.send_signal(2)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()


def _load(ticks: int, cycle: int = 2000) -> None:
    """The background's load: bench_pipeline's robot load per tick (a WhiskerWrenchArray of 32
    rows per tick at LOAD_RATE wrenches/s, a pose every 10 ms sent one period ahead), ``ticks``
    ticks or until its stdin closes; the payloads of ``cycle`` ticks and their poses sent again
    and again, each with its stamp moved on (encoding ``ticks`` payloads would take minutes; the
    robot's pose jumps back to the start of its arc every cycle). Prints ``ready``,
    waits for a line, then ``sent N`` at the end."""
    from vibrissa.msgs import RobotPose, WhiskerWrenchArray
    from vibrissa.runtime import Node

    tick_s = pipeline.WHISKERS / LOAD_RATE
    payloads = [bytearray(p) for p in pipeline._payloads(min(cycle, ticks), "tick", True, tick_s)]
    at = [p.index(b"\xa5stamp\xcb") + 7 for p in payloads]  # the float64 after the key
    poses, due = pipeline._poses(min(cycle, ticks), tick_s, pipeline.POSE_PERIOD_S)
    poses = [bytearray(p) for p in poses]
    pose_at = [p.index(b"\xa5stamp\xcb") + 7 for p in poses]
    pose_period = pipeline.POSE_PERIOD_S
    due = np.arange(int((ticks - 1) * tick_s / pose_period) + 2) * pose_period - pose_period
    stop = threading.Event()
    sent = 0

    class Stopped(Exception):
        pass

    with Node("load", "/bench", handle_signals=False) as node:
        pub = node.create_publisher("wrench", WhiskerWrenchArray, wait_for=["reconstructor"],
                                    hwm=100_000)
        pose_pub = node.create_publisher(pipeline.POSE_TOPIC, RobotPose,
                                         wait_for=["reconstructor"], hwm=100_000)
        for topic in ("wrench", pipeline.POSE_TOPIC):
            if not node.wait_for_subscribers(topic, ["reconstructor"], 60.0):
                raise SystemExit("reconstructor not ready")
        print("ready", flush=True)
        sys.stdin.readline()
        threading.Thread(target=lambda: (sys.stdin.readline(), stop.set()), daemon=True).start()

        def send(i: int) -> None:
            nonlocal sent
            if stop.is_set():
                raise Stopped
            k = i % len(payloads)
            struct.pack_into(">d", payloads[k], at[k], pipeline._stamp(i, tick_s))
            pub.publish_raw(bytes(payloads[k]))
            sent = i + 1

        def send_pose(j: int) -> None:
            k = j % len(poses)
            struct.pack_into(">d", poses[k], pose_at[k], pipeline._stamp(j, pose_period))
            pose_pub.publish_raw(bytes(poses[k]))

        try:
            pipeline._pace(send, ticks, LOAD_RATE, 1, np.zeros(ticks), (send_pose, due))
        except Stopped:
            pass
        pub.publish_end_of_stream(node.fqn)
    print(f"sent {sent}", flush=True)


def measure(config: str, domain: int, tmp: Path, passes: int, rate: float, load_s: float,
            log: Path | None = None) -> Run:
    """One run of ``config``; the launch's output into ``log``."""
    background = Background(tmp, load_s) if config == "loaded" else None
    proc = launch(domain, subprocess.PIPE, f"out:={tmp / 'map'}", f"rate:={rate:g}",
                  f"passes:={passes}")
    output = Output(proc)
    contacts: list[tuple[float, float]] = []
    meshes: list[tuple[float, float]] = []
    clouds: list[float] = []
    final = False
    notes: list[str] = []
    try:
        deadline = time.monotonic() + 60
        while output.first(re.compile(r"proxy: .*\(domain")) is None:
            if time.monotonic() > deadline or proc.poll() is not None:
                raise SystemExit(f"the launch did not start:\n{output.text()}")
            time.sleep(0.05)
        with Subscriber({CONTACT: ContactPointArray, MESH: SurfaceMesh, CLOUD: ContactCloud},
                        Endpoints.for_domain(domain)) as sub:
            deadline = time.monotonic() + 600
            while not final and time.monotonic() < deadline:
                if background is not None and background.started is None and output.first(
                        SIMULATED) is not None:
                    background.go()
                rx = sub.receive(0.05)
                now = time.monotonic()
                if rx is None:
                    if proc.poll() is not None and now - output.lines[-1][0] > 5:
                        notes.append("the launch ended without the mesh's EndOfStream")
                        break
                    continue
                msg = rx.msg
                if isinstance(msg, EndOfStream):
                    final = final or rx.topic == MESH
                elif isinstance(msg, ContactPointArray):
                    if len(msg.whisker_ids):
                        contacts.append((now, msg.stamp))
                elif isinstance(msg, SurfaceMesh):
                    meshes.append((now, msg.stamp))
                elif isinstance(msg, ContactCloud):
                    clouds.append(now)
            mesh_lost = sub.counters[MESH].lost
        covered, rows = None, (0, 0)
        if background is not None:  # still sending at the final mesh, started before contacts
            covered = (background.started is not None and bool(contacts)
                       and background.started <= contacts[0][0]
                       and background.load.poll() is None)
        rc = proc.wait(120)
        if rc != 0:
            notes.append(f"launch exit {rc}")
        load = os.getloadavg()[0]
        if background is not None:
            rows = background.stop()
    finally:
        if proc.poll() is None:
            proc.kill()
        if background is not None:
            background.close()
    if log is not None:
        log.write_text(output.text())
    stream_end = contacts[-1][0] if contacts else np.inf
    updates = [(float(m.group(1)), t <= stream_end) for t, line in output.lines
               if (m := UPDATE.search(line))]
    first_mesh = meshes[0][0] - contacts[0][0] if contacts and meshes else np.nan
    return Run(config, delays(np.array(contacts), np.array(meshes), np.array(clouds), final),
               updates, first_mesh, load, mesh_lost, covered, rows, notes)


def _pct(values: np.ndarray, q: float) -> float:
    return float(np.percentile(values, q)) if len(values) else np.nan


def _median(values: Sequence[float]) -> float:
    finite = [v for v in values if np.isfinite(v)]
    return statistics.median(finite) if finite else np.nan


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs per configuration")
    parser.add_argument("--passes", type=int, default=2, help="legs of the robot's path")
    parser.add_argument("--rate", type=float, default=500.0, help="path samples per second")
    parser.add_argument("--configs", default=",".join(CONFIGS),
                        help=f"of {', '.join(CONFIGS)}")
    parser.add_argument("--load-s", type=float, default=600.0,
                        help="longest run of the 32-whisker x 1 kHz stream of 'loaded', s (it "
                        "ends with the launch)")
    parser.add_argument("--domain", type=int, default=10_000 + os.getpid() % 400 * 2,
                        help="the launches' ZeroMQ domain (default: one of 10000-10798, away "
                        "from the tests')")
    parser.add_argument("--logs", type=Path, default=None,
                        help="a folder to keep each run's launch output in")
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "_load":
        _load(int(argv[1]))
        return 0
    args = parser.parse_args(argv)
    configs = [c for c in CONFIGS if c in args.configs.split(",")]
    if not configs or set(args.configs.split(",")) - set(CONFIGS):
        parser.error(f"--configs: choose from {', '.join(CONFIGS)}")
    if args.logs is not None:
        args.logs.mkdir(parents=True, exist_ok=True)
    print(f"robot demo, passes {args.passes}, {args.rate:g} samples/s; map_period_s "
          f"{PERIOD_S:g} s; {os.cpu_count()} cores", flush=True)
    runs: list[Run] = []
    for repeat in range(args.repeat):
        for config in configs[::-1] if repeat % 2 else configs:
            with tempfile.TemporaryDirectory() as tmp:
                run = measure(config, args.domain, Path(tmp), args.passes, args.rate,
                              args.load_s, args.logs / f"{repeat}-{config}.log"
                              if args.logs is not None else None)
            runs.append(run)
            d = run.delays
            extra = (f"; 32x1kHz from the first contact to the final mesh: {run.load_covered}, "
                     f"rows placed {run.rows[0]}/{run.rows[1]}" if config == "loaded" else "")
            fits = ", ".join(f"{u:.1f}{'' if live else ' (after)'}" for u, live in run.updates)
            print(f"  {repeat} {config:6s} contacts {len(d.delay)} (final only "
                  f"{int(d.final_only.sum())}, never {d.never}); p50 {_pct(d.delay, 50):.2f} "
                  f"p95 {_pct(d.delay, 95):.2f} max {_pct(d.delay, 100):.2f} s, live p95 "
                  f"{_pct(d.live, 95):.2f}; next update p95 {_pct(d.next_update, 95):.2f}; "
                  f"first mesh {run.first_mesh_s:.1f} s after the first contact; fits {fits} s; "
                  f"meshes lost {run.mesh_lost}; load {run.load:.1f}{extra} "
                  f"{' '.join(run.notes)}", flush=True)
    print(f"\nmedians over the runs of each run's figure (delays in s; P = map_period_s = "
          f"{PERIOD_S:g} s; contacts: totals)")
    print(f"{'':16} {'runs':>4} {'contacts':>8} {'final':>6} {'never':>5} {'p50':>6} {'p95':>6} "
          f"{'max':>6} {'p95/P':>6} {'live p95':>8} {'1st mesh':>8} {'1st fit s':>9} {'final s':>8} "
          f"{'load':>5}")
    for config in configs:
        mine = [r for r in runs if r.config == config]
        counts = (f"{sum(len(r.delays.delay) for r in mine):8d} "
                  f"{sum(int(r.delays.final_only.sum()) for r in mine):6d} "
                  f"{sum(r.delays.never for r in mine):5d}")
        common = (f"{_median([r.first_mesh_s for r in mine]):8.1f} "
                  f"{_median([r.updates[0][0] if r.updates else np.nan for r in mine]):9.1f} "
                  f"{_median([r.updates[-1][0] if r.updates else np.nan for r in mine]):8.1f} "
                  f"{_median([r.load for r in mine]):5.1f}")
        for name, of in (("mesh", lambda r: r.delays.delay),
                         ("next update", lambda r: r.delays.next_update)):
            p50, p95, top = (_median([_pct(of(r), q) for r in mine]) for q in (50, 95, 100))
            live = (f"{_median([_pct(r.delays.live, 95) for r in mine]):8.2f}" if name == "mesh"
                    else f"{'':8}")
            print(f"{config + ' ' + name:16} {len(mine):4d} {counts} {p50:6.2f} {p95:6.2f} "
                  f"{top:6.2f} {p95 / PERIOD_S:6.2f} {live} {common}")
        p95 = _median([_pct(r.delays.delay, 95) for r in mine])
        print(f"{config}: p95 <= 2 x map_period_s: "
              f"{'met' if p95 <= 2 * PERIOD_S else 'NOT MET'} (p95 / P = {p95 / PERIOD_S:.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
