"""A launch whose data can no longer arrive ends by itself and says what was lost: the demo's
reconstructor killed late in the stream and respawned after the wrench source has sent its
EndOfStream and ended (real processes)."""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from vibrissa.runtime.node import EXIT_LOST_DATA

DEMO = Path(__file__).parents[2] / "launch" / "demo.yaml"
DOMAIN = 500 + os.getpid() % 90 * 2  # its own graph: no tool of another test finds it at 0
DEADLINE_S = 300.0  # generous: the demo takes 10-20 s idle, minutes at load 20


class ReconstructorKiller:
    """Reads the launch's log lines; SIGKILLs the reconstructor it started once the wrench
    source said it published ``at`` messages or more."""

    def __init__(self, at: int) -> None:
        self.at, self.pid, self.killed = at, 0, False

    def see(self, line: str) -> None:
        started = re.search(r"started 'reconstructor' \(pid (\d+)\)", line)
        self.pid = int(started.group(1)) if started else self.pid
        published = re.search(r"wrench_source.*?(\d+) published", line)
        if not self.killed and published and int(published.group(1)) >= self.at:
            assert self.pid, line
            os.kill(self.pid, signal.SIGKILL)
            self.killed = True


def test_a_node_respawned_after_its_input_ended_ends_the_launch_with_the_loss(tmp_path: Path) -> None:
    launch_file = tmp_path / "demo.yaml"
    launch_file.write_text(DEMO.read_text().replace(
        '      respawn: "$(var respawn)"\n', "      respawn: true\n      respawn_delay: 20\n"))
    assert "respawn_delay: 20" in launch_file.read_text()
    proc = subprocess.Popen([sys.executable, "-m", "vibrissa.cli.launch", str(launch_file),
                             "rate:=1000", f"out:={tmp_path / 'out'}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env=os.environ | {"VIBRISSA_DOMAIN_ID": str(DOMAIN)})
    lines: queue.Queue[str | None] = queue.Queue()

    def read() -> None:
        assert proc.stderr is not None
        for line in proc.stderr:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=read, daemon=True).start()
    deadline = time.monotonic() + DEADLINE_S
    seen: list[str] = []
    killer = ReconstructorKiller(at=5000)
    try:
        while (line := lines.get(timeout=max(0.1, deadline - time.monotonic()))) is not None:
            seen.append(line)
            killer.see(line)
        rc = proc.wait(timeout=max(1.0, deadline - time.monotonic()))
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
    err = "".join(seen)
    assert killer.killed, err
    assert rc == EXIT_LOST_DATA, err
    assert "data did not arrive in full" in err
    summary = re.search(r"reconstructor .* received (\d+)", err)
    source = re.search(r"wrench_source .* published (\d+)", err)
    assert summary and source and int(summary.group(1)) < int(source.group(1)), err


def test_the_map_report_states_what_was_lost_before_the_map(tmp_path: Path) -> None:
    """The reconstructor killed early and respawned while the stream goes on: the map is
    written, and its own report says the reconstructor fell short, not only the launch."""
    launch_file = tmp_path / "demo.yaml"
    launch_file.write_text(DEMO.read_text().replace(
        '      respawn: "$(var respawn)"\n', "      respawn: true\n      respawn_delay: 0.5\n"))
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "vibrissa.cli.launch", str(launch_file),
                             "rate:=400", f"out:={out}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env=os.environ | {"VIBRISSA_DOMAIN_ID": str(DOMAIN)})
    assert proc.stderr is not None
    deadline = time.monotonic() + DEADLINE_S
    seen: list[str] = []
    killer = ReconstructorKiller(at=500)
    try:
        for line in proc.stderr:
            seen.append(line)
            killer.see(line)
            assert time.monotonic() < deadline, "".join(seen)
        rc = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    err = "".join(seen)
    assert killer.killed and rc == EXIT_LOST_DATA, err
    report = json.loads((out / "report.json").read_text())
    short = {u["node"]: u for u in report["upstream"]}
    reconstructor_in = short["/whisker0/reconstructor"]
    source = re.search(r"wrench_source .* published (\d+)", err)
    assert source and reconstructor_in["sent_to_it"] == int(source.group(1)) > 0, err
    assert 0 < reconstructor_in["short"] == reconstructor_in["sent_to_it"] - reconstructor_in["received"]
    assert report["upstream_lost"] == reconstructor_in["short"]
    assert "LOST UPSTREAM" in (out / "report.txt").read_text()
