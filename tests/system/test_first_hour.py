"""What a new user meets in the first hour, with real processes: a graph that is live while
it simulates, Ctrl-C that stops it at once, and a run that misses the object said plainly."""

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
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from vibrissa.msgs import EndOfStream, WhiskerWrenchArray
from vibrissa.nodes.wrench_source import PROGRESS_PERIOD_S
from vibrissa.wire import Endpoints, Subscriber

LAUNCH = Path(__file__).parents[2] / "launch"
DOMAIN = 8200 + os.getpid() % 12 * 128  # +0..+120; ports below the ephemeral ones (32768-60999)


class Launch:
    """``vibrissa launch`` in the background; stdout and stderr lines with arrival times."""

    def __init__(self, path: Path, *words: str, domain: int | None = None,
                 prefix: Sequence[str] = (), grace_s: float = 5.0) -> None:
        env = {k: v for k, v in os.environ.items() if not k.startswith("VIBRISSA_")}
        if domain is not None:
            env["VIBRISSA_DOMAIN_ID"] = str(domain)
        self.proc = subprocess.Popen(  # prefix: ip netns exec NS (it execs the launcher)
            [*prefix, sys.executable, "-m", "vibrissa.cli.main", "launch", "--grace",
             str(grace_s), str(path), *words], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, env=env)
        self.lines: list[tuple[float, str]] = []
        self._readers = [threading.Thread(target=self._pump, args=(pipe,), daemon=True)
                         for pipe in (self.proc.stdout, self.proc.stderr)]
        for reader in self._readers:
            reader.start()

    def _pump(self, pipe: Any) -> None:
        for line in pipe:
            self.lines.append((time.monotonic(), line))

    def text(self) -> str:
        return "".join(line for _, line in sorted(self.lines))

    def wait_line(self, pattern: str, timeout: float = 60.0) -> float:
        """Arrival time of the first line matching ``pattern``."""
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for t, line in list(self.lines):
                if rx.search(line):
                    return t
            if self.proc.poll() is not None:
                for reader in self._readers:
                    reader.join(5)
                if not any(rx.search(line) for _, line in self.lines):
                    break
            time.sleep(0.02)
        pytest.fail(f"no line matching {pattern!r}:\n{self.text()}")

    def wait(self, timeout: float = 120.0) -> int:
        try:
            rc = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            pytest.fail(f"launch did not end within {timeout} s:\n{self.text()}")
        for reader in self._readers:
            reader.join(5)
        return rc

    def stream_then_stop(self, topic: str, domain: int, enough: Callable[[list[Any]], bool]
                         ) -> tuple[list[Any], int]:
        """Messages of ``topic`` (none an EndOfStream: the stream goes on) until
        ``enough(messages)``, then SIGINT; (the messages, the launch's exit status)."""
        messages: list[Any] = []
        try:
            self.wait_line(r"proxy: .*\(domain")
            with Subscriber({topic: WhiskerWrenchArray}, Endpoints.for_domain(domain)) as sub:
                while not enough(messages):
                    rx = sub.receive(300.0)
                    assert rx is not None and not isinstance(rx.msg, EndOfStream), self.text()
                    messages.append(rx.msg)
            assert self.proc.poll() is None, self.text()
            self.proc.send_signal(signal.SIGINT)
            return messages, self.wait(120)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()


def demo_with(tmp_path: Path, **wrench_params: Any) -> Path:
    """The demo launch file with some wrench source parameters changed."""
    doc = yaml.safe_load((LAUNCH / "demo.yaml").read_text())
    doc = copy.deepcopy(doc)
    for entry in doc["launch"]:
        node = entry.get("node")
        if node and node["name"] == "wrench_source":
            params = {p["name"]: p for p in node["param"]}
            for key, value in wrench_params.items():
                if key in params:
                    params[key]["value"] = value
                else:
                    node["param"].append({"name": key, "value": value})
    path = tmp_path / "demo.launch.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_samples_stream_while_the_sweeps_are_solved(tmp_path: Path) -> None:
    """The first sample goes out long before the simulation ends, and the stream is spread
    over the simulation instead of one burst at its end."""
    launch = Launch(LAUNCH / "demo.yaml", f"out:={tmp_path / 'map'}", domain=DOMAIN)
    endpoints = Endpoints.for_domain(DOMAIN)
    arrivals: list[float] = []
    try:
        launch.wait_line(r"proxy: .*\(domain")
        with Subscriber({"/whisker0/wrench": WhiskerWrenchArray}, endpoints) as sub:
            while True:
                rx = sub.receive(60.0)
                assert rx is not None, launch.text()
                if isinstance(rx.msg, EndOfStream):
                    break
                arrivals.append(time.monotonic())
        assert launch.wait() == 0, launch.text()
    finally:
        if launch.proc.poll() is None:
            launch.proc.kill()
    launch.wait_line(r"wrench_source\] .*done: 10474 messages")
    (done,) = [line for _, line in launch.lines if "done: 10474 messages" in line]
    found = re.search(r"published in ([0-9.]+) s", done)
    assert found is not None, done
    solving_s = float(found.group(1))  # from the first sweep's start to the last message
    progress = [line for _, line in launch.lines if "sweeps ended" in line and "done:" not in line]
    if solving_s > PROGRESS_PERIOD_S + 0.5:  # progress is logged every 2 s while it works (a
        assert progress, launch.text()  # fast hour of this machine solves the demo in 2.0 s)
    span = arrivals[-1] - arrivals[0]
    assert len(arrivals) > 10_000 - 500  # the subscriber may join a moment late
    assert span > 0.5 * solving_s, launch.text()  # spread out, not a burst at the end
    share_in_first_half = sum(t < arrivals[0] + span / 2 for t in arrivals) / len(arrivals)
    assert share_in_first_half > 0.05  # a burst at the end: none (0.084 with two CPU burners)


def test_ctrl_c_during_the_simulation_stops_every_node_within_a_second(tmp_path: Path) -> None:
    # a grace for a loaded machine: the mapper may be amid an update and then writes the final
    # map (3.5 s and 3.9 s at load 6), and no node may need escalating
    launch = Launch(LAUNCH / "demo.yaml", f"out:={tmp_path / 'map'}", "step:=0.0002",
                    domain=DOMAIN + 40, grace_s=60.0)
    # every node past its start (a node still importing ends by SIGINT's default action): the
    # mapper listens once the reconstructor's output is ready for it
    launch.wait_line(r"\['/mapper'\] ready on /whisker0/contact")
    launch.wait_line(r"wrench_source\] .*sweeps ended 0/5")  # mid-simulation
    sent = time.monotonic()
    launch.proc.send_signal(signal.SIGINT)
    rc = launch.wait(30)
    elapsed = time.monotonic() - sent
    text = launch.text()
    assert rc == 128 + signal.SIGINT, text
    assert "escalating" not in text and "SIGKILL" not in text, text
    for name in ("wrench_source", "reconstructor", "mapper"):
        assert re.search(rf"{name}\s+stopped by launcher \(exit 0\)", text), text
    assert "Traceback" not in text
    if "no map written" in text:  # stopped before a contact point arrived
        assert elapsed < 3.0, text  # three nodes, one after the other, each well within 1 s
    else:  # the final map of the points received, within the launcher's grace
        report = json.loads((tmp_path / "map" / "report.json").read_text())
        assert (report["final"], report["ended_by"]) == (True, "stop"), text
        assert report["n_points"] > 0


def test_ctrl_c_while_the_robot_scene_is_simulated_stops_its_worker_processes(
        tmp_path: Path) -> None:
    # the robot's wrench source simulates its scene (8 whiskers, worker processes) before it
    # plays it: several seconds of Step 1 that a Ctrl-C must not wait for (it did, past the
    # launcher's grace, and the source was killed)
    scene = yaml.safe_load((LAUNCH / "robot" / "scene.yaml").read_text(encoding="utf-8"))
    scene["path"] = "path.csv"  # the robot's path, 10 times as finely sampled: a long Step 1
    (tmp_path / "scene.yaml").write_text(yaml.safe_dump(scene), encoding="utf-8")
    path = np.loadtxt(LAUNCH / "robot" / "path.csv", delimiter=",", skiprows=1)
    s = np.linspace(0.0, len(path) - 1.0, 10 * len(path) - 9)
    fine = np.column_stack([np.interp(s, np.arange(len(path)), column) for column in path.T])
    fine[:, 4:] /= np.linalg.norm(fine[:, 4:], axis=1, keepdims=True)
    np.savetxt(tmp_path / "path.csv", fine, delimiter=",", header="t,x,y,z,qx,qy,qz,qw",
               comments="", fmt="%.17g")
    launch = Launch(LAUNCH / "robot.yaml", f"out:={tmp_path / 'map'}",
                    f"scene:={tmp_path / 'scene.yaml'}", domain=DOMAIN + 100)
    launch.wait_line(r"wrench_source\] .*simulating 8 whisker\(s\) along the path")
    launch.proc.send_signal(signal.SIGINT)
    rc = launch.wait(60)
    text = launch.text()
    assert rc == 128 + signal.SIGINT, text
    assert re.search(r"stopped with \d of 8 whisker\(s\) done while simulating", text), text
    assert "escalating" not in text and "Traceback" not in text, text
    assert re.search(r"wrench_source\s+stopped by launcher \(exit 0\)", text), text


def test_ctrl_c_while_the_nodes_still_start_is_quiet(tmp_path: Path) -> None:
    launch = Launch(LAUNCH / "demo.yaml", f"out:={tmp_path / 'map'}", domain=DOMAIN + 60)
    launch.wait_line(r"started 'mapper'")
    time.sleep(0.5)  # past the interpreter's own start (~0.1 s), every node still importing
    launch.proc.send_signal(signal.SIGINT)
    rc = launch.wait(30)
    text = launch.text()
    assert rc == 128 + signal.SIGINT, text
    assert "Traceback" not in text and "KeyboardInterrupt" not in text, text
    assert "escalating" not in text, text


def test_a_run_that_never_touches_the_object_fails_and_says_why(tmp_path: Path) -> None:
    launch = Launch(demo_with(tmp_path, y0=[2.0, 2.5]), f"out:={tmp_path / 'map'}",
                    domain=DOMAIN + 80)
    rc = launch.wait()
    text = launch.text()
    assert rc == 1, text
    for y0 in ("2", "2.5"):
        assert f"the trail y0={y0} (units of L) never touches" in text
    assert "the map is empty: no contact point arrived" in text
    assert "required node 'mapper' exited with code 3" in text
    assert "THE MAP IS EMPTY" in (tmp_path / "map" / "report.txt").read_text()


def test_trails_that_miss_a_sphere_are_named(tmp_path: Path) -> None:
    launch = Launch(LAUNCH / "demo.yaml", f"out:={tmp_path / 'map'}", "step:=0.004",
                    "surface:=sphere:r=0.3,cz=0.8", domain=DOMAIN + 120)
    assert launch.wait() == 0, launch.text()
    text = launch.text()
    for y0 in ("-0.4", "0.4"):
        assert f"the trail y0={y0} (units of L) never touches" in text
    assert "the trail y0=0.2 (units of L)" not in text
