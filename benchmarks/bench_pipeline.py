"""Latency and throughput of the node graph: wrenches published -> contact points received.

Pipeline (every box its own process, real ZeroMQ on loopback), as nodes connect: node
publishers bind and announce their endpoint in their status on the proxy, subscribers connect
there (docs/ARCHITECTURE.md), so data skips the proxy::

    load --/bench/wrench--> reconstructor --/bench/contact--> sink (here)
    (and their statuses, with the endpoints, through the proxy)

Floor, in the same run, with the same payload and the same pacing::

    load (bare PUB) --> echo (SUB -> PUB, forwards the bytes) --> sink (bare SUB)

and, below every pipeline, the machine's own wake-up latency (``timer``): one process that
sleeps until each tick is due, as the load does, and sends nothing; its "latency" is how late
it woke. A message through any chain here wakes two processes (the middle one and the sink),
each at the mercy of the same scheduler: the timer's p99 is the tail of one wake-up in that
minute. ``busy`` is the floor whose echo spins ``--busy-us`` (default 150) on each message
before forwarding it: a node's work without its code, for the tail that work alone makes.
Further, the pipeline with CURVE on every socket (``curve``: keys of ``vibrissa keys``, the ZAP guards;
the sink connects with the graph's key), and the floor through the broker (``proxied``): the
same bare processes connected through the proxy, as tools and raw publishers are (what the
broker costs without any work)::

    load --/bench/wrench--> proxy --> echo --/bench/contact--> proxy --> sink

``veth`` (root and iproute2) is ``curve`` over two hosts: the proxy, the load and the
reconstructor in a network namespace of their own (the robot), the sink here (the
workstation), joined by a veth pair.

Two ways to send a tick of 32 whiskers at ``rate`` wrenches/s in total: *per wrench*, one
WhiskerWrenchArray of one row per whisker (32 messages per tick; latency per wrench, its
ContactPointArray), and *per tick*, one WhiskerWrenchArray of 32 rows (latency per tick, its
ContactPointArray). The
load sends pre-encoded payloads and records the send time of each message; the sink records the
receive time of each by sequence number (the transport header's ``seq``, so the sink decodes
nothing). Loss is sent - received (every benchmark wrench has a contact). A rate is
*sustained* when nothing is lost and the sink is done within ``max(50 ms, 5 %)`` of the send
duration after the last send (no backlog grows). ``first p50`` is the median latency of the
first message of each tick (whisker 0 per wrench; every message per tick). With ``--repeat``
every figure is the median over the repeats (runs interleaved, the chains' order reversed every
other repeat: none always runs right after another), sustained counts the repeats,
and ``pooled p99 x`` is the ratio of the p99 of all repeats' latencies together: a run's p99 is
set by the few stalls of a few ms that happen to fall in it (on a shared VM they hit the floor
as much as the pipeline), and pooling the repeats counts more of them.

Every run records the share of the CPUs' time the hypervisor gave to other guests meanwhile
(``steal``, Linux's /proc/stat): on a shared VM it ranges from 0 to tens of per cent from minute
to minute, and a run with steal holds stalls of several ms that no process here causes. ``calm
p99`` is the median p99 of the calm runs (steal < 1 %) and their count.

``late %`` is the share of the messages later than 2 ms (a p99 under 2 ms is a share under
1 %), ``in a row`` how many late messages there are per run of them. A stall of the machine
(on this VM most likely the kernel's kdamond, which holds a CPU for 1-4 ms every 512 ms:
docs/PERFORMANCE.md) makes every chain late for a few ticks, as many as it takes to catch up.

The robot graph (``robot``): the pipeline of ``vibrissa``, but every row is in its clamp frame
(``w00/clamp``, ..., no pose fields) and the reconstructor places it through a robot description
(32 whiskers, each its own mount, L and EI, in a temporary file: ``robot``) and the robot's pose
X_WR (RobotPose ``world`` -> ``base_link``, 100 Hz on /bench/pose, sent by the load),
interpolated at the wrench's stamp::

    load --/bench/wrench, /bench/pose--> reconstructor (robot, pose_topic) --/bench/contact--> sink

Tick k carries the stamp k x the tick period and pose j the stamp j x 10 ms (one timeline). The
frame buffer never extrapolates, so a wrench stamped t waits for a pose stamped >= t: sent in real time, poses at
100 Hz would hold a wrench up to 10 ms, which is the pose stream's period, not the graph's cost.
``robot`` sends each pose one pose period ahead of its stamp (the pose stamped t + 10 ms with the
tick stamped t, as a predicting localisation would), so no wrench waits and the latency, from the
wrench's send, is the graph's. ``robot-rt`` (only with ``--modes``) sends each pose at its stamp:
its latency includes that wait. After every run of a node the bench reads the reconstructor's row
counters from its status: ``no pose`` counts rows placed without a pose, and a run where a row got
no point (``contacts`` < rows) is not sustained. ``vs vib`` is the overhead over the pipeline
(``vibrissa``, same unit, rate and repeat): mode / vibrissa - 1 of p50 and p99, the median over
the repeats.

Run: ``python benchmarks/bench_pipeline.py [--duration 2] [--rates 1000,...] [--repeat 1]
[--units wrench,tick] [--modes bare,...,robot]``. Not a test.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgpack
import numpy as np
import zmq

from vibrissa.launch.launcher import die_with_parent
from vibrissa.msgs import NodeStatus, Ping
from vibrissa.msgs.codec import peek_type
from vibrissa.wire import Endpoints
from vibrissa.wire.security import Keys, create_keys

if TYPE_CHECKING:
    from vibrissa.scene import Whisker

WHISKERS = 32
TOPIC = "/bench/wrench"
CONTACT = "/bench/contact"
UNITS = ("wrench", "tick")  # a WhiskerWrenchArray of one row per whisker, or of 32 per tick
MODES = ("timer", "bare", "busy", "proxied", "vibrissa", "curve", "veth", "robot", "robot-rt")
# one process waking at each tick (no message), the floor, the floor with work per message, the
# floor through the proxy, the pipeline, the pipeline encrypted and authenticated, the robot graph
# (poses one period ahead), the robot graph with poses in real time
DEFAULT_MODES = ("timer", "bare", "proxied", "vibrissa", "curve", "robot")
FLOORS = ("timer", "bare", "busy", "proxied")
CALM_STEAL = 0.01  # a run is calm when the hypervisor stole less than this share of the CPUs
LATE_S = 0.002  # the target's p99, s: the table counts the messages later than this
ROBOT_MODES = ("robot", "robot-rt")
POSE_TOPIC = "/bench/pose"
POSE_PERIOD_S = 0.01  # the robot's poses at 100 Hz
RECONSTRUCTOR = ["-m", "vibrissa.nodes.reconstructor"]  # how the chains start the node
ROW_COUNTERS = ("contacts", "no_contact", "bad_pose", "no_pose", "unknown_whisker", "wrong_frame")
# the reconstructor's counters of rows: each row lands in one


# -- helper processes (python bench_pipeline.py _proxy | _load | _echo ...) ----------------------


def _robot() -> tuple[Whisker, ...]:
    """The robot of the ``robot`` modes: WHISKERS whiskers ``w00``.., each its own rod (L 30-61 mm,
    EI 1.0-2.55e-4 N m^2) and mount X_RC: 4 columns x 8 rows on the robot's right, pointing right
    (C's +z along R's -y), each tilted its own way."""
    from vibrissa.frames import Transform
    from vibrissa.scene import Whisker

    return tuple(Whisker(f"w{j:02d}", 0.03 + 0.001 * j, 1e-4 * (1 + 0.05 * j),
                         Transform.from_xyz_rpy([-0.01 * (j // 8), -0.02, 0.005 * (j % 8)],
                                                [np.pi / 2 + 0.02 * j, 0.01 * j, -0.015 * j]))
                 for j in range(WHISKERS))


def _write_robot(path: Path) -> None:
    """``_robot()`` as a robot description (a file of ``whiskers``, `load_robot`'s format)."""
    import yaml

    path.write_text(yaml.safe_dump({"whiskers": [
        {"name": w.name, "length_m": w.length_m, "ei_nm2": w.ei_nm2,
         "mount": {"position_m": w.X_RC.translation.tolist(),
                   "quaternion_xyzw": w.X_RC.quaternion_xyzw.tolist()}}
        for w in _robot()]}, sort_keys=False), encoding="utf-8")


def _stamp(k: int, period_s: float) -> float:
    """The stamp of sample ``k`` of a stream at ``period_s``, s, rounded to the ns so that a tick
    and a pose meant at the same time carry the same float."""
    return round(k * period_s, 9)


def _payloads(n: int, unit: str, robot: bool, tick_s: float) -> list[bytes]:
    """``n`` encoded messages, seq 0..n-1, tick k stamped k x ``tick_s``: a WhiskerWrenchArray
    of one row each (``unit`` wrench, WHISKERS per tick) or of WHISKERS rows (tick). Row j of
    a tick is whisker j's, cycling over the wrenches that have a contact on its rod: ``whisker{j}``
    (the unit rod) with its clamp pose in world, or (``robot``) the robot's ``w{j}`` in its clamp
    frame, without pose."""
    from vibrissa.frames import WORLD_FRAME, clamp_frame
    from vibrissa.msgs import WhiskerWrenchArray
    from vibrissa.msgs.codec import encode
    from vibrissa.reconstruct import reconstruct_si
    from vibrissa.units import RodScale

    rng = np.random.default_rng(1)
    # wrenches of one contact each (else Step 2 says MULTI_CONTACT): a force f at a point r of
    # the rod's bending plane (through the clamp's z axis, at a random angle), m0 = r x f
    p0 = rng.uniform(-1, 1, (512, 3))
    phi = rng.uniform(0, 2 * np.pi, 512)
    radial = np.column_stack([np.cos(phi), np.sin(phi), np.zeros(512)])
    axial = np.array([0.0, 0.0, 1.0])
    r = rng.uniform(0.0, 0.5, (512, 1)) * radial + rng.uniform(0.5, 1.0, (512, 1)) * axial
    f0 = rng.normal(size=(512, 1)) * radial + rng.normal(size=(512, 1)) * axial
    m0 = np.cross(r, f0)
    whiskers = _robot() if robot else ()
    names = [w.name for w in whiskers] or [f"whisker{j}" for j in range(WHISKERS)]
    rods = [w.scale for w in whiskers] or [RodScale()] * WHISKERS
    frames = [clamp_frame(name) for name in names]
    # each whisker's candidate wrenches in SI (W, 512, 3), and those with a contact on its rod
    f_si = np.stack([f0 * rod.force_n for rod in rods])
    m_si = np.stack([m0 * rod.moment_nm for rod in rods])
    valid = reconstruct_si(np.tile([0.0, 0.0, 0.0, 1.0], (WHISKERS * 512, 1)),
                           np.tile(p0, (WHISKERS, 1)), f_si.reshape(-1, 3), m_si.reshape(-1, 3),
                           [rod for rod in rods for _ in range(512)]).valid.reshape(WHISKERS, 512)
    choices = [np.flatnonzero(v) for v in valid]
    counts = np.array([len(c) for c in choices])
    # row r (tick r // W, whisker j = r % W) takes whisker j's valid wrench number r mod its count
    r = np.arange(n * WHISKERS // _per_tick(unit))
    j = r % WHISKERS
    k = np.concatenate(choices)[np.cumsum(counts)[j] - counts[j] + r % counts[j]]
    p_rows, f_rows, m_rows = p0[k], f_si[j, k], m_si[j, k]
    q_rows = np.tile([0.0, 0.0, 0.0, 1.0], (len(r), 1))

    def pose(rows: slice) -> dict[str, Any]:
        """The clamp poses of ``rows`` in world (none for the robot's)."""
        return {} if robot else {"pose_frame_id": WORLD_FRAME, "clamp_position": p_rows[rows],
                                 "clamp_orientation": q_rows[rows]}

    out = []
    for i in range(n):
        if unit == "tick":
            s = slice(i * WHISKERS, (i + 1) * WHISKERS)
            out.append(encode(WhiskerWrenchArray(
                stamp=_stamp(i, tick_s), seq=i, whisker_ids=names, frame_ids=frames,
                f0=f_rows[s], m0=m_rows[s], **pose(s))))
        else:
            row = slice(i, i + 1)
            out.append(encode(WhiskerWrenchArray(
                stamp=_stamp(i // WHISKERS, tick_s), seq=i, whisker_ids=[names[i % WHISKERS]],
                frame_ids=[frames[i % WHISKERS]], f0=f_rows[row], m0=m_rows[row], **pose(row))))
    return out


def _poses(ticks: int, tick_s: float, lead_s: float) -> tuple[list[bytes], np.ndarray]:
    """The robot's poses X_WR (RobotPose, world -> base_link) every POSE_PERIOD_S from stamp 0 to
    the first after the last of ``ticks`` ticks stamped k x ``tick_s``, encoded, and when each is
    due, s on the ticks' clock: ``lead_s`` before its stamp. The robot drives an arc (0.1 m/s,
    0.3 rad/s) and sways, so every lookup interpolates."""
    from vibrissa.frames import ROBOT_FRAME, WORLD_FRAME
    from vibrissa.msgs import RobotPose
    from vibrissa.msgs.codec import encode

    stamps = np.array([_stamp(j, POSE_PERIOD_S)
                       for j in range(int((ticks - 1) * tick_s / POSE_PERIOD_S) + 2)])
    payloads = [encode(RobotPose(
        stamp=float(t), frame_id=WORLD_FRAME, child_frame_id=ROBOT_FRAME,
        position=[0.1 * t, 0.02 * np.sin(2.0 * t), 0.0],
        orientation=[0.0, 0.0, np.sin(0.15 * t), np.cos(0.15 * t)])) for t in stamps]
    return payloads, stamps - lead_s


def _per_tick(unit: str) -> int:
    """Messages per tick."""
    return WHISKERS if unit == "wrench" else 1


def _pace(send: Callable[[int], None], n: int, rate: float, per_tick: int, t_send: np.ndarray,
          side: tuple[Callable[[int], None], np.ndarray] | None = None) -> float:
    """Call ``send(i)`` for i < n, ``per_tick`` messages per tick, ticks of WHISKERS wrenches
    at ``rate`` wrenches/s (tick k due k x WHISKERS / ``rate`` s after the start). ``side`` =
    (``send_side``, ``due_s``): a second stream, ``send_side(j)`` at ``due_s[j]`` s after the
    start (before a tick due at the same time), what is left of it after the last tick.
    Returns the start (time.time(), s): tick k is due then + k x WHISKERS / ``rate``."""
    tick = WHISKERS / rate
    t0 = time.perf_counter() + 0.05
    clock_offset = time.time() - time.perf_counter()
    send_side, side_due = side if side is not None else (send, np.zeros(0))
    j = 0

    def until(due: float) -> None:
        delay = t0 + due - time.perf_counter()
        if delay > 0:
            time.sleep(delay)

    for start in range(0, n, per_tick):
        due = (start // per_tick) * tick
        while j < len(side_due) and side_due[j] <= due + 1e-9:
            until(side_due[j])
            send_side(j)
            j += 1
        until(due)
        for i in range(start, min(n, start + per_tick)):
            t_send[i] = time.perf_counter() + clock_offset
            send(i)
    for k in range(j, len(side_due)):
        until(side_due[k])
        send_side(k)
    return t0 + clock_offset


def _load(mode: str, unit: str, endpoint: str, n: int, rate: float, out: str) -> None:
    per_tick = _per_tick(unit)
    payloads = _payloads(n, unit, mode in ROBOT_MODES, WHISKERS / rate)
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
        from vibrissa.msgs import RobotPose, WhiskerWrenchArray
        from vibrissa.runtime import Node

        with Node("load", "/bench", handle_signals=False) as node:
            pub = node.create_publisher("wrench", WhiskerWrenchArray, wait_for=["reconstructor"],
                                        hwm=n + 10)
            topics = ["wrench"]
            side = None
            if mode in ROBOT_MODES:
                poses, due = _poses(n // per_tick, WHISKERS / rate,
                                    POSE_PERIOD_S if mode == "robot" else 0.0)
                pose_pub = node.create_publisher(POSE_TOPIC, RobotPose, wait_for=["reconstructor"],
                                                 hwm=len(poses) + 10)
                topics.append(POSE_TOPIC)
                side = (lambda j: pose_pub.publish_raw(poses[j]), due)
            for topic in topics:
                if not node.wait_for_subscribers(topic, ["reconstructor"], 60.0):
                    raise SystemExit("reconstructor not ready")
            print("ready", flush=True)
            sys.stdin.readline()
            _pace(lambda i: pub.publish_raw(payloads[i]), n, rate, per_tick, t_send, side)
            pub.publish_end_of_stream(node.fqn)
    np.save(out, t_send)


def _timer(n: int, rate: float, out: str) -> None:
    """Wake at each of ``n`` ticks as the load does, sending nothing; save how late each wake-up
    was, s: the machine's floor under any pipeline, whose every message wakes two processes."""
    t_wake = np.zeros(n)
    start = _pace(lambda i: None, n, rate, 1, t_wake)
    np.save(out, t_wake - (start + np.arange(n) * WHISKERS / rate))


def _echo(source: str, endpoint: str, via_proxy: bool, busy_s: float = 0.0) -> None:
    """Forward every message; ``via_proxy``: connect to the proxy's ``endpoint`` and forward
    /bench/wrench as /bench/contact, else bind ``endpoint`` and forward as it came; ``busy_s``:
    spin that long on each message before forwarding it (a node's work, without its code)."""
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
    print("ready", flush=True)  # on a loaded machine our imports can outlast the bench's 1.5 s sleep
    out_topic = CONTACT.encode() + b"\0"
    try:
        while True:
            frames = sub.recv_multipart()
            done = time.perf_counter() + busy_s
            while time.perf_counter() < done:
                pass
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

    host = os.environ.get(VETH_HOST_ENV, "127.0.0.1")
    proxy = Proxy(Endpoints.free(host).with_keys(Keys.from_env()), zmq.Context(), hwm=1_000_000)
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
    rows: int  # wrenches sent
    counters: dict[str, int] = field(default_factory=dict)  # the reconstructor's, at the end
    steal: float = np.nan  # share of the CPUs' time the hypervisor gave to others meanwhile

    @property
    def lost(self) -> int:
        return self.sent - self.received

    @property
    def no_point(self) -> int:
        """Rows the reconstructor published no point for (0 for the floors)."""
        return self.rows - self.counters["contacts"] if self.counters else 0

    @property
    def sustained(self) -> bool:
        return (self.lost == 0 and self.no_point == 0
                and self.backlog_s <= max(0.05, 0.05 * self.send_s))

    def late(self) -> tuple[float, float]:
        """Share of the messages later than LATE_S (p99 < LATE_S means under 1 %), and how many
        in a row on average: one stall of the machine makes a run of late ticks as long as the
        chain takes to catch up."""
        late = self.latency_s > LATE_S
        if not late.any():
            return 0.0, 0.0
        starts = np.count_nonzero(late[1:] & ~late[:-1]) + int(late[0])
        return float(late.mean()), float(np.count_nonzero(late)) / starts

    def pct(self, q: float, first: bool = False) -> float:
        """Percentile ``q`` of the latency, us (``first``: of the first message of each tick)."""
        latency = self.first_latency_s if first else self.latency_s
        return float(np.percentile(latency, q)) * 1e6 if len(latency) else np.nan


def _cpu_times() -> tuple[float, float]:
    """(steal, total) CPU time of all CPUs since boot, in clock ticks (Linux's /proc/stat; NaN
    elsewhere): steal is time the hypervisor ran another guest on a CPU of this one."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
    except OSError:
        return np.nan, np.nan
    ticks = [int(x) for x in fields[:8]]  # user nice system idle iowait irq softirq steal
    return float(ticks[7]), float(sum(ticks))


def _steal(before: tuple[float, float]) -> float:
    """Share of the CPUs' time stolen since ``before`` (a `_cpu_times`)."""
    steal, total = _cpu_times()
    return (steal - before[0]) / max(total - before[1], 1.0)


def _python(*args: str, netns: str | None = None, **kwargs: Any) -> subprocess.Popen[str]:
    """A helper process that ends with the bench, however the bench ends (a killed bench once
    left a reconstructor that kept 2 % of a CPU busy retrying its peers); in the network
    namespace ``netns`` if given."""
    prefix = ["ip", "netns", "exec", netns] if netns else []
    return subprocess.Popen([*prefix, sys.executable, *args], text=True,
                            preexec_fn=die_with_parent(os.getpid()), **kwargs)


VETH_HOST_ENV = "BENCH_PROXY_HOST"
VETH_ROBOT, VETH_HERE = "10.214.0.1", "10.214.0.2"


@contextlib.contextmanager
def _robot_namespace() -> Iterator[str]:
    """A network namespace (the robot's host) joined to this one by a veth pair: the robot at
    10.214.0.1, this end 10.214.0.2 (root and iproute2)."""
    name = f"vbench{os.getpid() % 100000}"
    def ip(*words: str) -> None:
        subprocess.run(["ip", *words], check=True, capture_output=True, timeout=30)
    ip("netns", "add", name)
    try:
        ip("-n", name, "link", "set", "lo", "up")
        ip("link", "add", f"{name}h", "type", "veth", "peer", "name", f"{name}r", "netns", name)
        ip("addr", "add", f"{VETH_HERE}/24", "dev", f"{name}h")
        ip("link", "set", f"{name}h", "up")
        ip("-n", name, "addr", "add", f"{VETH_ROBOT}/24", "dev", f"{name}r")
        ip("-n", name, "link", "set", f"{name}r", "up")
        yield name
    finally:
        subprocess.run(["ip", "link", "del", f"{name}h"], capture_output=True, timeout=30)
        subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=30)


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


def _node_status(endpoints: Endpoints, node: str, accept: Callable[[NodeStatus], bool],
                 timeout_s: float) -> NodeStatus:
    """The first status of ``node`` that ``accept`` takes, else its last one in ``timeout_s``."""
    from vibrissa.wire import STATUS_TOPIC, Subscriber

    last = None
    with Subscriber({STATUS_TOPIC: NodeStatus}, endpoints) as statuses:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            rx = statuses.receive(0.1)
            if rx is not None and isinstance(rx.msg, NodeStatus) and rx.msg.node == node:
                last = rx.msg
                if accept(last):
                    break
    if last is None:
        raise SystemExit(f"no status from {node} within {timeout_s} s")
    return last


def _announced(endpoints: Endpoints, node: str, topic: str, timeout_s: float = 30.0) -> str:
    """The direct endpoint ``node`` announces for ``topic`` in its status (a subscriber that
    reads nothing else connects there, as ``Subscriber`` does)."""
    status = _node_status(endpoints, node, lambda s: topic in s.endpoints, timeout_s)
    if topic not in status.endpoints:
        raise SystemExit(f"{node} announced no endpoint for {topic} within {timeout_s} s")
    return status.endpoints[topic]


def measure(mode: str, unit: str, rate: float, duration_s: float, tmp: Path,
            busy_s: float = 0.0) -> Run:
    """One run of the pipeline (``mode`` = ``vibrissa``, ``curve``, ``robot``, ``robot-rt``),
    the floor (``bare``; ``busy``: its echo spins ``busy_s`` per message) or the floor through
    the proxy (``proxied``), sending a message per wrench or per tick (``unit``) at ``rate``
    wrenches/s."""
    per_tick = _per_tick(unit)
    n = int(rate * duration_s) // WHISKERS * per_tick
    rows = n * WHISKERS // per_tick
    counters: dict[str, int] = {}
    out = tmp / f"send-{mode}-{unit}-{int(rate)}.npy"
    context: zmq.Context[Any] = zmq.Context()
    sink = context.socket(zmq.SUB)
    sink.setsockopt(zmq.LINGER, 0)
    sink.setsockopt(zmq.RCVHWM, 1_000_000)
    helpers: list[subprocess.Popen[str]] = []
    me = str(Path(__file__).resolve())
    stack = contextlib.ExitStack()
    try:
        if mode == "timer":
            ticks = n // per_tick
            before = _cpu_times()
            _python(me, "_timer", str(ticks), str(rate), str(out)).wait(60 + 2 * duration_s)
            late = np.load(out)
            return Run(mode, unit, rate, ticks, ticks, late, late, duration_s, 0.0, 0,
                       steal=_steal(before))
        if mode in ("bare", "busy"):
            probe = context.socket(zmq.PUB)  # find two free ports
            load_ep = f"tcp://127.0.0.1:{probe.bind_to_random_port('tcp://127.0.0.1')}"
            echo_ep = f"tcp://127.0.0.1:{probe.bind_to_random_port('tcp://127.0.0.1')}"
            probe.close()
            load = _python(me, "_load", "bare", unit, load_ep, str(n), str(rate), str(out),
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE)
            helpers.append(load)
            assert load.stdout is not None and load.stdout.readline().strip() == "ready"
            echo = _python(me, "_echo", load_ep, echo_ep, "direct",
                           str(busy_s if mode == "busy" else 0.0), stdout=subprocess.PIPE)
            helpers.append(echo)
            assert echo.stdout is not None and echo.stdout.readline().strip() == "ready"
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
            echo = _python(me, "_echo", sub_ep, pub_ep, "proxy", "0", stdout=subprocess.PIPE)
            helpers.append(echo)
            assert echo.stdout is not None and echo.stdout.readline().strip() == "ready"
            load = _python(me, "_load", "proxied", unit, pub_ep, str(n), str(rate), str(out),
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE)
            helpers.append(load)
            assert load.stdout is not None and load.stdout.readline().strip() == "ready"
            time.sleep(1.5)
            header_seq = False
        else:
            keys = None
            secured: dict[str, str] = {}
            netns = stack.enter_context(_robot_namespace()) if mode == "veth" else None
            if mode in ("curve", "veth"):
                create_keys(tmp / "keys")
                keys = Keys.load(tmp / "keys")
                keys.connect_with(sink)
                secured = keys.to_env()
            env = {**os.environ, "VIBRISSA_LOG_LEVEL": "WARNING", **secured,
                   **({VETH_HOST_ENV: VETH_ROBOT} if netns else {})}
            proxy = _python(me, "_proxy", stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env,
                            netns=netns)
            helpers.append(proxy)
            assert proxy.stdout is not None
            pub_ep, sub_ep = proxy.stdout.readline().split()
            env.update({"VIBRISSA_PUB_ENDPOINT": pub_ep, "VIBRISSA_SUB_ENDPOINT": sub_ep})
            sink.setsockopt(zmq.SUBSCRIBE, CONTACT.encode() + b"\0")
            sink.connect(sub_ep)
            params: list[str] = []
            if mode in ROBOT_MODES:
                _write_robot(tmp / "robot.yaml")
                params = ["--param", f"robot:={tmp / 'robot.yaml'}",
                          "--param", f"pose_topic:={POSE_TOPIC}"]
            helpers.append(_python(*RECONSTRUCTOR, "--name",
                                   "reconstructor", "--namespace", "/bench", *params, env=env,
                                   netns=netns))
            endpoints = Endpoints(pub_ep, sub_ep, keys)
            sink.connect(_announced(endpoints, "/bench/reconstructor", CONTACT))
            load = _python(me, "_load", mode, unit, "", str(n), str(rate), str(out),
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env, netns=netns)
            helpers.append(load)
            assert load.stdout is not None and load.stdout.readline().strip() == "ready"
            header_seq = True
        assert load.stdin is not None
        before = _cpu_times()
        load.stdin.write("go\n")
        load.stdin.flush()
        t_recv = _sink(sink, n, header_seq, timeout_s=30.0 + 2 * duration_s)
        steal = _steal(before)
        if header_seq:  # a node: where every row went, once it has counted them all
            counters = _node_status(
                endpoints, "/bench/reconstructor",
                lambda s: sum(s.counters.get(key, 0) for key in ROW_COUNTERS) >= rows, 5.0
            ).counters
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
        stack.close()
    ok = np.isfinite(t_recv)
    latency = t_recv - t_send
    first = latency[::per_tick]
    send_s = float(t_send[-1] - t_send[0]) if n > 1 else 0.0
    backlog = float(np.nanmax(t_recv) - t_send[-1]) if ok.any() else np.inf
    return Run(mode, unit, rate, n, int(ok.sum()), latency[ok], first[np.isfinite(first)],
               send_s, backlog, rows, counters, steal)


def _pooled_p99(runs: list[Run]) -> float:
    """p99 of the latencies of all ``runs`` together, us (NaN without any)."""
    latency = np.concatenate([r.latency_s for r in runs]) if runs else np.zeros(0)
    return float(np.percentile(latency, 99)) * 1e6 if len(latency) else np.nan


def _ratio(runs: list[Run], base: list[Run], q: float) -> float:
    """Median over the repeats of ``runs``' percentile ``q`` over ``base``'s of the same repeat
    (NaN without a base)."""
    if not base:
        return np.nan
    return float(np.median([a.pct(q) / b.pct(q) for a, b in zip(runs, base, strict=True)]))


def _calm_p99(runs: list[Run]) -> str:
    """Median p99 of the calm runs (steal below CALM_STEAL), us, and how many there were."""
    calm = [r.pct(99) for r in runs if r.steal < CALM_STEAL]
    return f"{np.median(calm):.0f} ({len(calm)})" if calm else "- (0)"


def _table(runs: list[Run], unit: str, rates: list[float], repeats: int,
           modes: list[str]) -> None:
    """Medians over the repeats per rate and mode; ratios are medians of per-repeat ratios."""
    what = "wrench published -> its ContactPointArray" if unit == "wrench" else (
        "WhiskerWrenchArray of a tick published -> its ContactPointArray")
    print(f"\nper {unit} ({what}); {repeats} run(s) each, medians; x: over bare; vs vib: "
          "over vibrissa - 1")
    header = (f"{'rate/s':>8} {'mode':>9} {'sent':>7} {'lost':>6} {'no pose':>7} {'p50 us':>9} "
              f"{'p99 us':>9} {'max us':>9} {'first p50':>9} {'backlog ms':>10} {'sustained':>9} "
              f"{'p50 x':>7} {'p99 x':>7} {'pooled p99 x':>12} {'vs vib p50':>10} "
              f"{'vs vib p99':>10} {'steal %':>7} {'calm p99 us':>14} {'late %':>6} {'in a row':>8}")
    print(header)
    print("-" * len(header))
    for rate in rates:
        by_mode = {mode: [r for r in runs if (r.unit, r.rate, r.mode) == (unit, rate, mode)]
                   for mode in modes}
        bare, vibrissa = by_mode.get("bare", []), by_mode.get("vibrissa", [])
        for mode, mine in by_mode.items():
            no_pose = (f"{max(r.counters.get('no_pose', 0) for r in mine):7d}"
                       if mine[0].counters else f"{'-':>7}")
            vs_vib = (f"{(_ratio(mine, vibrissa, 50) - 1) * 100:+9.0f}% "
                      f"{(_ratio(mine, vibrissa, 99) - 1) * 100:+9.0f}%"
                      if mode not in (*FLOORS, "vibrissa") else f"{'-':>10} {'-':>10}")
            print(f"{rate:8.0f} {mode:>9} {mine[0].sent:7d} {max(r.lost for r in mine):6d} "
                  f"{no_pose} "
                  f"{np.median([r.pct(50) for r in mine]):9.0f} "
                  f"{np.median([r.pct(99) for r in mine]):9.0f} "
                  f"{np.median([r.pct(100) for r in mine]):9.0f} "
                  f"{np.median([r.pct(50, first=True) for r in mine]):9.0f} "
                  f"{np.median([r.backlog_s for r in mine]) * 1e3:10.1f} "
                  f"{sum(r.sustained for r in mine):>7d}/{len(mine)} "
                  f"{_ratio(mine, bare, 50):7.1f} {_ratio(mine, bare, 99):7.1f} "
                  f"{_pooled_p99(mine) / _pooled_p99(bare):12.1f} {vs_vib} "
                  f"{np.median([r.steal for r in mine]) * 100:7.1f} {_calm_p99(mine):>14} "
                  f"{np.median([r.late()[0] for r in mine]) * 100:6.2f} "
                  f"{np.median([r.late()[1] for r in mine]):8.1f}")
    for mode in modes:
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
    if argv and argv[0] == "_timer":
        _timer(int(argv[1]), float(argv[2]), argv[3])
        return 0
    if argv and argv[0] == "_echo":
        _echo(argv[1], argv[2], argv[3] == "proxy", float(argv[4]))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=2.0, help="seconds per run")
    parser.add_argument("--rates", default="1000,4000,8000,16000,32000,64000",
                        help="aggregate wrenches/s to try (32 whiskers per tick)")
    parser.add_argument("--repeat", type=int, default=1, help="runs per rate, mode and unit")
    parser.add_argument("--units", default=",".join(UNITS),
                        help="what one message carries: wrench, tick or both")
    parser.add_argument("--busy-us", type=float, default=150.0,
                        help="work per message of the busy floor's echo, us")
    parser.add_argument("--modes", default=",".join(DEFAULT_MODES),
                        help=f"chains to run, of {', '.join(MODES)} (ratios need bare and vibrissa)")
    args = parser.parse_args(argv)
    rates = [float(r) for r in args.rates.split(",")]
    units = [u for u in args.units.split(",") if u]
    if not units or set(units) - set(UNITS):
        parser.error(f"--units: choose from {', '.join(UNITS)}")
    modes = [m for m in MODES if m in args.modes.split(",")]  # in MODES' order
    if not modes or set(args.modes.split(",")) - set(MODES):
        parser.error(f"--modes: choose from {', '.join(MODES)}")
    print(f"{os.cpu_count()} CPUs; {WHISKERS} whiskers per tick; {args.duration:g} s per run",
          flush=True)
    runs: list[Run] = []
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeat):
            for rate in rates:
                for unit in units:
                    for mode in modes[::-1] if repeat % 2 else modes:
                        run = measure(mode, unit, rate, args.duration, Path(tmp),
                                      args.busy_us * 1e-6)
                        runs.append(run)
                        rows = (f"  no point {run.no_point}  no_pose {run.counters['no_pose']}"
                                if run.counters else "")
                        print(f"  {repeat} {unit:6s} {mode:8s} {rate:8.0f}/s  p50 "
                              f"{run.pct(50):9.0f} us  p99 {run.pct(99):9.0f} us  first p50 "
                              f"{run.pct(50, first=True):9.0f} us  lost {run.lost}  backlog "
                              f"{run.backlog_s * 1e3:.1f} ms{rows}  steal "
                              f"{run.steal * 100:.1f} %", flush=True)
    for unit in units:
        _table(runs, unit, rates, args.repeat, modes)
    nodes = [mode for mode in modes if mode not in FLOORS]
    for unit in units:
        for mode in nodes:
            target = [r for r in runs if (r.unit, r.rate, r.mode) == (unit, 32000, mode)]
            if not target:
                continue
            lost = max(r.lost for r in target)
            no_point, no_pose = (max(r.no_point for r in target),
                                 max(r.counters["no_pose"] for r in target))
            plain = [r for r in runs if (r.unit, r.rate, r.mode) == (unit, 32000, "vibrissa")]
            overhead = (f"; over per-{unit} vibrissa (same run): p50 "
                        f"{(_ratio(target, plain, 50) - 1) * 100:+.0f} %, p99 "
                        f"{(_ratio(target, plain, 99) - 1) * 100:+.0f} %, pooled p99 "
                        f"{(_pooled_p99(target) / _pooled_p99(plain) - 1) * 100:+.0f} %"
                        if plain and mode != "vibrissa" else "")
            print(f"32 whiskers x 1 kHz, per {unit} ({mode}): "
                  f"{'zero loss' if lost == 0 else f'LOST {lost}'}, rows without a point "
                  f"{no_point}, no_pose {no_pose}, sustained in "
                  f"{sum(r.sustained for r in target)}/{len(target)} runs, p99 "
                  f"{np.median([r.pct(99) for r in target]):.0f} us (median), pooled "
                  f"{_pooled_p99(target):.0f} us, in calm runs (steal < {CALM_STEAL:.0%}) "
                  f"{_calm_p99(target)}{overhead}")
        plain = [r for r in runs if (r.unit, r.mode) == (unit, "vibrissa")]
        for mode in nodes:
            other = [r for r in runs if (r.unit, r.mode) == (unit, mode)]
            if plain and other and mode != "vibrissa":
                print(f"{mode} over vibrissa per {unit}: p50 x{_ratio(other, plain, 50):.2f}, "
                      f"p99 x{_ratio(other, plain, 99):.2f} "
                      f"(median over rates and repeats of {mode} / vibrissa)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
