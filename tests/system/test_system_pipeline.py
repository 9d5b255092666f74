"""The node graph with real processes: the launcher, its proxy on free loopback ports, ZeroMQ.

The launch files under test are the shipped ones (``launch/*.yaml``), made smaller (one or two
coarse sweeps) and extended with the test's own probe node, through which the test process
subscribes to the graph: the readiness gates wait for it, so nothing is lost at start-up.
Every wait has a deadline so that a hang fails fast.
"""

from __future__ import annotations

import copy
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import msgpack
import numpy as np
import pytest
import yaml
import zmq

from tests.streaming.test_live_tick import recorder
from vibrissa.frames import quaternion_matrices
from vibrissa.msgs import (
    ContactPointArray,
    EndOfStream,
    NodeStatus,
    Ping,
    WhiskerWrenchArray,
)
from vibrissa.msgs.codec import encode
from vibrissa.reconstruct import reconstruct
from vibrissa.runtime import Node
from vibrissa.runtime.node import EXIT_LOST_DATA
from vibrissa.surfaces import parse_surface
from vibrissa.sweep import Trail, first_contact, simulate_sweeps
from vibrissa.wire import STATUS_TOPIC
from vibrissa.wire.bag import BagReader
from vibrissa.wire.transport import Endpoints

LAUNCH = Path(__file__).parents[2] / "launch"
SURFACE = "paraboloid:a=0.5,b=1,h=0.4"
Y0 = [-0.3, 0.3]
STEP = 0.01
MU = 0.2
TIMEOUT_S = 120.0
CONTACT = "/whisker0/contact"
T = TypeVar("T")
WRENCH = "/whisker0/wrench"


# -- launch files and the launcher ---------------------------------------------------------------


def entries(name: str) -> list[dict[str, Any]]:
    """The ``launch:`` list of a shipped launch file."""
    return copy.deepcopy(yaml.safe_load((LAUNCH / name).read_text())["launch"])


def node(launch: list[dict[str, Any]], name: str) -> dict[str, Any]:
    """The ``node:`` body named ``name``."""
    return next(e["node"] for e in launch if "node" in e and e["node"]["name"] == name)


def set_param(body: dict[str, Any], key: str, value: Any) -> None:
    """Set (or add) parameter ``key`` of a ``node:`` body."""
    params = body.setdefault("param", [])
    for p in params:
        if p["name"] == key:
            p["value"] = value
            return
    params.append({"name": key, "value": value})


class Launch:
    """``python -m vibrissa.cli.launch FILE ARGS``, with its output collected by threads."""

    def __init__(self, tmp_path: Path, launch: list[dict[str, Any]], *words: str) -> None:
        path = tmp_path / f"test-{time.monotonic_ns()}.launch.yaml"
        path.write_text(yaml.safe_dump({"launch": launch}, sort_keys=False))
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "vibrissa.cli.launch", "--grace", "3", str(path), *words],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.out: list[str] = []
        self.err: list[str] = []
        self._readers = [threading.Thread(target=self._pump, args=(pipe, lines), daemon=True)
                         for pipe, lines in ((self.proc.stdout, self.out),
                                             (self.proc.stderr, self.err))]
        for reader in self._readers:
            reader.start()

    @staticmethod
    def _pump(pipe: Any, lines: list[str]) -> None:
        for line in pipe:
            lines.append(line)

    def wait_line(self, pattern: str, timeout: float = 60.0) -> re.Match[str]:
        """First launcher stderr line matching ``pattern`` (fails after ``timeout``)."""
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in list(self.err):
                match = rx.search(line)
                if match:
                    return match
            if self.proc.poll() is not None and not any(rx.search(x) for x in self.err):
                break
            time.sleep(0.02)
        pytest.fail(f"no line matching {pattern!r}\n{self.text()}")

    def endpoints(self) -> Endpoints:
        match = self.wait_line(r"proxy: publishers -> (\S+), subscribers -> (\S+)", 30)
        return Endpoints(match.group(1), match.group(2))

    def wait(self, timeout: float = TIMEOUT_S) -> int:
        try:
            rc = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            pytest.fail(f"launch did not end within {timeout} s\n{self.text()}")
        for reader in self._readers:
            reader.join(5)
        return rc

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def text(self) -> str:
        return "".join(self.out) + "".join(self.err)


class Probe:
    """The test's node on the graph: collects what arrives on ``topics`` and node statuses."""

    def __init__(self, endpoints: Endpoints, topics: list[str]) -> None:
        self.node = Node("probe", endpoints=endpoints, handle_signals=False)
        self.sub = self.node.create_subscriber({t: None for t in topics})
        self.status_sub = self.node.create_subscriber({STATUS_TOPIC: NodeStatus})
        self.statuses: dict[str, NodeStatus] = {}

    def collect(self, timeout: float = TIMEOUT_S) -> tuple[list[ContactPointArray], EndOfStream]:
        """Contact point arrays until the first EndOfStream."""
        return self._until_end(ContactPointArray, timeout)

    def _until_end(self, kind: type[T], timeout: float) -> tuple[list[T], EndOfStream]:
        """Messages of type ``kind`` until the first EndOfStream (others are ignored)."""
        got: list[T] = []
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            rx = self.sub.receive(0.2)
            if rx is None:
                continue
            if isinstance(rx.msg, EndOfStream):
                return got, rx.msg
            if isinstance(rx.msg, kind):
                got.append(rx.msg)
        self.wait_status("", lambda status: False, 1.0)  # the graph's last word, for the failure
        states = "; ".join(f"{fqn} {status.state} {status.counters}"
                           for fqn, status in sorted(self.statuses.items()))
        pytest.fail(f"no EndOfStream within {timeout} s ({len(got)} {kind.__name__}); the nodes' "
                    f"last statuses: {states or 'none'}")

    def status_of(self, fqn: str, predicate: Callable[[NodeStatus], bool],
                  timeout: float = 30.0) -> NodeStatus:
        """The first status of ``fqn`` that satisfies ``predicate``."""
        status = self.wait_status(fqn, predicate, timeout)
        if status is None:
            pytest.fail(f"no matching status of {fqn} within {timeout} s: {self.statuses.get(fqn)}")
        return status

    def wait_status(self, fqn: str, predicate: Callable[[NodeStatus], bool],
                    timeout: float) -> NodeStatus | None:
        """:meth:`status_of`, or None after ``timeout`` (the node may still be starting)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            rx = self.status_sub.receive(0.1)
            if rx is not None and isinstance(rx.msg, NodeStatus):
                self.statuses[rx.msg.node] = rx.msg
                if rx.msg.node == fqn and predicate(rx.msg):
                    return rx.msg
        return None

    def close(self) -> None:
        self.node.close(drain_s=0.0)


def small_demo(out: Path, recorder_bag: Path | None = None) -> list[dict[str, Any]]:
    """launch/demo.yaml with two sweeps, the probe as a consumer, optionally a wrench bag."""
    launch = entries("demo.yaml")
    source = node(launch, "wrench_source")
    set_param(source, "y0", Y0)
    set_param(node(launch, "reconstructor"), "wait_for", ["/mapper", "/probe"])
    if recorder_bag is not None:
        set_param(source, "wait_for", ["reconstructor", "/recorder"])
        launch.insert(len(launch) - 1, {"node": {
            "pkg": "vibrissa", "exec": "recorder", "name": "recorder", "param": [
                {"name": "output", "value": str(recorder_bag)},
                {"name": "topics", "value": [WRENCH]},
                {"name": "chunk_size", "value": 4096},  # many chunks: a cut keeps most
            ]}})
    return launch


def library_contacts() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points, s1 and forces of the same sweeps computed in-process (``reconstruct``)."""
    sweeps = simulate_sweeps(parse_surface(SURFACE), [Trail(y, MU) for y in Y0], STEP)
    rec = reconstruct(np.vstack([s.p0 for s in sweeps]), np.vstack([s.f0 for s in sweeps]),
                      np.vstack([s.m0 for s in sweeps]))
    assert rec.valid.all()
    return rec.point, rec.s1, rec.force


def run_to_end(tmp: Path, launch_entries: list[dict[str, Any]], *words: str
               ) -> tuple[int, list[ContactPointArray], EndOfStream, Launch]:
    """Launch, collect the contact points until their end of stream, wait for the launch to end;
    returns (exit status, points, end of stream, the ended launch)."""
    launch = Launch(tmp, launch_entries, *words)
    probe = Probe(launch.endpoints(), [CONTACT])
    try:
        points, eos = probe.collect()
        rc = launch.wait()
    finally:
        probe.close()
        launch.kill()
    return rc, points, eos, launch


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """One run of the (small) demo with a recorder of the wrench topic."""
    tmp = tmp_path_factory.mktemp("demo")
    out, bag = tmp / "out", tmp / "wrench.mcap"
    rc, points, eos, launch = run_to_end(tmp, small_demo(out, bag), f"out:={out}",
                                         f"step:={STEP}", f"mu:={MU}")
    yield {"rc": rc, "points": points, "eos": eos, "out": out, "bag": bag, "tmp": tmp,
           "text": launch.text(), "stdout": "".join(launch.out)}


# -- the tests -----------------------------------------------------------------------------------


def test_demo_matches_the_library(demo_run: dict[str, Any]) -> None:
    assert demo_run["rc"] == 0, demo_run["text"]
    points: list[ContactPointArray] = demo_run["points"]  # one per wrench, a row each
    ref_point, ref_s1, ref_force = library_contacts()
    assert [p.seq for p in points] == list(range(len(ref_point)))
    assert demo_run["eos"].count == len(points)
    got = np.vstack([p.point for p in points])
    np.testing.assert_allclose(got, ref_point, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.concatenate([p.s1 for p in points]), ref_s1, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.vstack([p.force for p in points]), ref_force, rtol=0, atol=1e-12)
    assert all(p.frame_id == "world" and p.whisker_ids == ["whisker0"] for p in points)
    # the mapper's files, announced on stdout
    out: Path = demo_run["out"]
    for name in ("cloud.ply", "mesh.ply", "map.png", "report.json", "report.txt"):
        assert (out / name).is_file(), name
        assert str(out / name) in demo_run["stdout"]
    report = json.loads((out / "report.json").read_text())
    assert report["n_points"] == len(points)
    frame = report["frames"][0]
    assert frame["n_triangles"] > 100 and frame["method"].startswith("gp implicit surface")
    assert report["max_reconstruction_error_m"] < 1e-9
    assert frame["mesh_to_surface_max"] < 0.005  # two lines 0.6 L apart, the known part
    assert len(frame["objects"][0]["next_sweeps"]) == 3


def _replay(tmp: Path, bag: Path) -> tuple[int, list[ContactPointArray], EndOfStream, str]:
    launch_entries = entries("replay_demo.yaml")
    set_param(node(launch_entries, "reconstructor"), "wait_for", ["/mapper", "/probe"])
    out = tmp / f"replay-{bag.stem}"
    rc, points, eos, launch = run_to_end(tmp, launch_entries, f"bag:={bag}", f"out:={out}")
    return rc, points, eos, launch.text()


def test_replay_of_the_recorded_wrenches_gives_identical_points(
        demo_run: dict[str, Any]) -> None:
    bag: Path = demo_run["bag"]
    n_wrenches = sum(1 for r in BagReader(bag) if r.type_name == WhiskerWrenchArray.TYPE_NAME)
    assert n_wrenches == len(demo_run["points"])
    rc, points, _, text = _replay(demo_run["tmp"], bag)
    assert rc == 0, text
    assert points == demo_run["points"]  # every field, bit for bit, stamps too (from the bag)


def test_a_cut_off_bag_replays_every_complete_message(demo_run: dict[str, Any]) -> None:
    bag: Path = demo_run["bag"]
    cut = demo_run["tmp"] / "cut.mcap"
    data = bag.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.6)])
    reader = BagReader(cut)
    complete = [r for r in reader if r.type_name == WhiskerWrenchArray.TYPE_NAME]
    assert reader.truncated and 0 < len(complete) < len(demo_run["points"])
    rc, points, eos, text = _replay(demo_run["tmp"], cut)
    assert rc == 0, text
    assert points == demo_run["points"][: len(complete)]
    assert eos.count == len(complete)


def _killed_reconstructor(tmp: Path, respawn: bool) -> tuple[Launch, list[ContactPointArray]]:
    """Run a slow (10 Hz) demo, kill -9 the reconstructor after 20 points; wait for the end."""
    launch_entries = small_demo(tmp / f"out-respawn-{respawn}")
    set_param(node(launch_entries, "wrench_source"), "y0", [0.3])
    # 20 s: 18 s for the respawned node to start while the stream goes on (on a loaded
    # machine its start took more than 7 s)
    set_param(node(launch_entries, "wrench_source"), "rate_hz", 10.0)
    launch = Launch(tmp, launch_entries, f"out:={tmp}/out-{respawn}", f"step:={STEP}",
                    f"respawn:={'true' if respawn else 'false'}")
    probe = Probe(launch.endpoints(), [CONTACT])
    points: list[ContactPointArray] = []
    try:
        pid = int(launch.wait_line(r"started 'reconstructor' \(pid (\d+)\)").group(1))
        deadline = time.monotonic() + 60
        while len(points) < 20 and time.monotonic() < deadline:
            rx = probe.sub.receive(0.2)
            if rx is not None and isinstance(rx.msg, ContactPointArray):
                points.append(rx.msg)
        assert len(points) >= 20, launch.text()
        os.kill(pid, signal.SIGKILL)
        if respawn:
            more, _ = probe.collect()
            points += more
        launch.wait()
    finally:
        probe.close()
        launch.kill()
    return launch, points


def test_killed_node_with_respawn_comes_back_and_the_run_completes(tmp_path: Path) -> None:
    launch, points = _killed_reconstructor(tmp_path, respawn=True)
    assert launch.proc.returncode == EXIT_LOST_DATA, launch.text()  # it completed, with loss
    assert "respawned 'reconstructor'" in launch.text()
    assert "'mapper' finished (exit 0)" in launch.text()
    seqs = [p.seq for p in points]
    assert seqs == sorted(seqs) and seqs[-1] > 20  # points after the respawn arrived too
    # what went by while it was down is said, in the summary and the exit status
    match = re.search(r"data did not arrive in full: 'reconstructor' lost (\d+)", launch.text())
    assert match and int(match.group(1)) > 0, launch.text()


def test_killed_node_without_respawn_fails_the_launch_naming_it(tmp_path: Path) -> None:
    launch, _ = _killed_reconstructor(tmp_path, respawn=False)
    assert launch.proc.returncode != 0
    assert re.search(r"launch failed: required node 'reconstructor' (was )?killed by SIGKILL",
                     launch.text()), launch.text()


def _good_wrench() -> WhiskerWrenchArray:
    rng = np.random.default_rng(11)
    while True:
        p0 = rng.uniform(-1, 1, 3)
        f0, m0 = (row[0] for row in recorder().single_contact(rng.normal(size=(1, 3)),
                                                               rng.normal(size=(1, 3))))
        if reconstruct(p0, f0, m0).valid[0]:
            return WhiskerWrenchArray(stamp=1.0, seq=42, whisker_ids=["w"], frame_ids=["w/clamp"],
                                      pose_frame_id="world", clamp_position=[p0],
                                      clamp_orientation=[[0, 0, 0, 1]], f0=[f0], m0=[m0])


def _bad_payloads(good: bytes) -> dict[str, bytes]:
    def edited(**changes: Any) -> bytes:
        body = msgpack.unpackb(good, raw=False)
        body.update(changes)
        return bytes(msgpack.packb(body))

    f0 = msgpack.unpackb(good, raw=False)["f0"]
    nan_f0 = {**f0, "data": np.array([np.nan, 0.0, 0.0], "<f8").tobytes()}
    mixed_keys = msgpack.unpackb(good, raw=False)
    mixed_keys.update({b"zz": 1, "yy": 2})  # once a TypeError inside the codec
    return {"field type": edited(seq="forty-two"), "version": edited(_v=99),
            "truncated": good[: len(good) // 2], "nan": edited(f0=nan_f0),
            "mixed keys": bytes(msgpack.packb(mixed_keys))}


def test_bad_messages_are_rejected_and_counted_and_the_node_carries_on(tmp_path: Path) -> None:
    launch_entries = [e for e in entries("demo.yaml") if "arg" in e]
    reconstructor = node(entries("demo.yaml"), "reconstructor")
    reconstructor.pop("respawn", None)
    set_param(reconstructor, "wait_for", ["/probe"])
    launch_entries.append({"node": reconstructor})
    launch = Launch(tmp_path, launch_entries)
    endpoints = launch.endpoints()
    probe = Probe(endpoints, [CONTACT])
    context: zmq.Context[Any] = zmq.Context()
    sock = context.socket(zmq.PUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(endpoints.pub)
    pub_id = 12345

    def send(payload: bytes, seq: int) -> None:
        sock.send_multipart([WRENCH.encode() + b"\0",
                             msgpack.packb({"pub": pub_id, "seq": seq}), payload])

    try:
        fqn = "/whisker0/reconstructor"
        # Ping (it announces seq 0) until the reconstructor reports the topic as seen.
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            send(encode(Ping(stamp=0.0, sender="/raw")), 0)
            status = probe.statuses.get(fqn)
            if status is not None and WRENCH in status.seen_topics:
                break
            probe.wait_status(fqn, lambda s: True, timeout=1.0)  # still starting: ping again
        good_wrench = _good_wrench()
        good = encode(good_wrench)
        bad = _bad_payloads(good)
        for seq, payload in enumerate(bad.values()):
            send(payload, seq)
            # the same on the status topic, which every node's heartbeat thread reads
            sock.send_multipart([STATUS_TOPIC.encode() + b"\0",
                                 msgpack.packb({"pub": pub_id + 1, "seq": seq}), payload])
        send(good, len(bad))
        rx = None
        deadline = time.monotonic() + 30
        while rx is None and time.monotonic() < deadline:
            rx = probe.sub.receive(0.2)
        assert rx is not None and isinstance(rx.msg, ContactPointArray), launch.text()
        assert rx.msg.seq == 42 and rx.msg.whisker_ids == ["w"]
        assert good_wrench.clamp_position is not None
        ref = reconstruct(good_wrench.clamp_position[0], good_wrench.f0[0], good_wrench.m0[0])
        np.testing.assert_allclose(rx.msg.point[0], ref.point[0], rtol=0, atol=1e-12)
        status = probe.status_of(fqn, lambda s: s.counters.get("contacts", 0) >= 1)
        assert status.state == "running"
        assert status.counters["rejected"] == len(bad), status.counters
        assert status.counters["received"] == 1 and status.counters["lost"] == 0
        assert launch.proc.poll() is None  # still running
        later = time.time()  # and its heartbeat too
        assert probe.status_of(fqn, lambda s: s.stamp > later).state == "running"
        assert launch.text().count("rejected message") >= len(bad)  # logged, not raised
    finally:
        sock.close()
        context.term()
        probe.close()
        launch.kill()


def test_points_held_for_a_late_subscriber_wait_for_it_at_the_end(tmp_path: Path) -> None:
    """A reconstructor that exits on its input's end (exit_on_eos) holds its points for its
    ``wait_for`` subscriber until that comes, within ``wait_timeout_s``: here it comes 3 s after
    the stream ended (a mapper still starting on a loaded machine), and gets every point and
    the EndOfStream."""
    launch_entries = [e for e in entries("demo.yaml") if "arg" in e]
    source = node(entries("demo.yaml"), "wrench_source")
    reconstructor = node(entries("demo.yaml"), "reconstructor")
    reconstructor.pop("respawn", None)
    set_param(reconstructor, "wait_for", ["/probe"])
    set_param(reconstructor, "exit_on_eos", True)
    launch_entries += [{"node": source}, {"node": reconstructor}]
    launch = Launch(tmp_path, launch_entries, "step:=0.01")
    probe = None
    try:
        endpoints = launch.endpoints()
        ended = launch.wait_line(r"reconstructor.*EndOfStream from \S+ \((\d+) samples\)", 300)
        time.sleep(3.0)  # the subscriber comes late: longer than a close's default drain (1 s)
        probe = Probe(endpoints, [CONTACT])
        msgs, _eos = probe.collect()
        assert len(msgs) == int(ended.group(1)), launch.text()
        assert launch.wait() == 0, launch.text()
    finally:
        if probe is not None:
            probe.close()
        launch.kill()


def _sweep_ticks(length: float, ei: float, whiskers: int) -> tuple[list[WhiskerWrenchArray],
                                                                    np.ndarray]:
    """The sweeps' samples as ticks of ``whiskers`` rows (SI, a turned clamp) plus one row per
    tick without force; returns the ticks and every row's quaternion rotation R_WC."""
    sweeps = simulate_sweeps(parse_surface(SURFACE), [Trail(y, MU) for y in Y0], STEP)
    p0, f0, m0 = (np.vstack([getattr(s, k) for s in sweeps]) for k in ("p0", "f0", "m0"))
    q = np.array([0.1, -0.3, 0.2, 0.9])
    ticks = []
    for seq, start in enumerate(range(0, len(p0), whiskers)):
        rows = slice(start, start + whiskers)
        n = len(p0[rows])
        ticks.append(WhiskerWrenchArray(
            stamp=float(seq), seq=seq, pose_frame_id="world",
            frame_ids=[f"w{i}/clamp" for i in range(n)] + ["idle/clamp"],
            whisker_ids=[f"w{i}" for i in range(n)] + ["idle"],
            clamp_position=np.vstack([p0[rows] * length, [0.0, 0.0, 0.0]]),
            clamp_orientation=np.tile(q, (n + 1, 1)),
            f0=np.vstack([f0[rows] * ei / length**2, np.zeros(3)]),
            m0=np.vstack([m0[rows] * ei / length, np.zeros(3)])))
    return ticks, quaternion_matrices(q[None])[0]


def test_array_ticks_over_the_wire_match_the_library(tmp_path: Path) -> None:
    length, ei = 0.05, 2e-3
    launch_entries = [e for e in entries("demo.yaml") if "arg" in e]
    reconstructor = node(entries("demo.yaml"), "reconstructor")
    reconstructor.pop("respawn", None)
    set_param(reconstructor, "wait_for", ["/probe"])
    set_param(reconstructor, "rod_length_m", length)
    set_param(reconstructor, "rod_ei_nm2", ei)
    launch_entries.append({"node": reconstructor})
    launch = Launch(tmp_path, launch_entries)
    probe = Probe(launch.endpoints(), [CONTACT])
    fqn = "/whisker0/reconstructor"
    try:
        ticks, R = _sweep_ticks(length, ei, whiskers=8)
        pub = probe.node.create_publisher(WRENCH, WhiskerWrenchArray, wait_for=[fqn])
        assert probe.node.wait_for_subscribers(WRENCH, [fqn], 30.0), launch.text()
        for tick in ticks:
            pub.publish(tick)
        pub.publish_end_of_stream(probe.node.fqn)
        got = probe.collect(60.0)[0]
        assert [a.seq for a in got] == [t.seq for t in ticks], launch.text()
        for tick, contacts in zip(ticks, got, strict=True):
            real = slice(0, len(tick.whisker_ids) - 1)  # the idle row has no contact
            assert contacts.whisker_ids == tick.whisker_ids[real]
            assert contacts.stamp == tick.stamp and contacts.frame_id == "world"
            ref = reconstruct(tick.clamp_position[real] / length,
                              tick.f0[real] * length**2 / ei, tick.m0[real] * length / ei,
                              np.broadcast_to(R, (len(contacts.whisker_ids), 3, 3)))
            assert ref.valid.all()
            np.testing.assert_allclose(contacts.point, ref.point * length, rtol=0, atol=1e-12)
            np.testing.assert_allclose(contacts.s1, ref.s1 * length, rtol=0, atol=1e-12)
            np.testing.assert_allclose(contacts.force, ref.force * ei / length**2, rtol=0,
                                       atol=1e-12)
            np.testing.assert_array_equal(contacts.phase, ref.phase)
        status = probe.status_of(fqn, lambda s: s.counters.get("no_contact", 0) >= len(ticks))
        n_rows = sum(len(t.whisker_ids) for t in ticks)
        assert status.counters["contacts"] == n_rows - len(ticks), status.counters
        assert status.counters["no_contact"] == len(ticks)
        assert status.counters["received"] == len(ticks) + 1  # and the EndOfStream
        assert status.counters["lost"] == 0
        assert status.subscribes[WRENCH] == WhiskerWrenchArray.TYPE_NAME
    finally:
        probe.close()
        launch.kill()


def test_a_simulated_whisker_array_runs_through_the_nodes(tmp_path: Path) -> None:
    # wrench_source with array: true publishes one WhiskerWrenchArray per clamp step of the
    # whole array; the reconstructor answers each with its points, the mapper maps them.
    launch_entries = small_demo(tmp_path / "out")
    set_param(node(launch_entries, "wrench_source"), "array", True)
    surface = parse_surface(SURFACE)
    x_grid = max(first_contact(surface, y)[0] for y in Y0)
    sweeps = simulate_sweeps(surface, [Trail(y, MU) for y in Y0], STEP, x_grid=x_grid)
    launch = Launch(tmp_path, launch_entries, f"out:={tmp_path / 'out'}", f"step:={STEP}",
                    f"mu:={MU}")
    probe = Probe(launch.endpoints(), [CONTACT])
    try:
        got = probe.collect()[0]
        assert launch.wait() == 0, launch.text()
    finally:
        probe.close()
        launch.kill()
    n_ticks = 1 + max(round((x_grid - s.x0[-1]) / STEP) for s in sweeps)
    assert [a.seq for a in got] == list(range(n_ticks))
    for i, sweep in enumerate(sweeps):
        whisker = f"whisker{i}"
        ticks = [round((x_grid - x0) / STEP) for x0 in sweep.x0]
        rows = [got[k].whisker_ids.index(whisker) for k in ticks]
        point = np.stack([got[k].point[row] for k, row in zip(ticks, rows, strict=True)])
        np.testing.assert_allclose(point, sweep.contact, rtol=0, atol=1e-12)
        # before its touch and after its detachment the whisker is free: no point
        free = set(range(n_ticks)) - set(ticks)
        assert free and all(whisker not in got[k].whisker_ids for k in free)
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["n_points"] == sum(s.n_steps for s in sweeps)
