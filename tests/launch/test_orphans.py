"""Nodes die with their launcher whatever they are doing: a node of the node runtime busy
computing (it never looks at its stop flag), its launcher SIGKILLed."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

from vibrissa.runtime.signals import ORPHAN_GRACE_S

DEADLINE_S = 180.0  # generous: a machine at load 20 starts a node in tens of seconds


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of ``pid`` (0 when it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def wait_for(predicate, what: str, timeout: float = DEADLINE_S) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.1)


FIXTURES = Path(__file__).parents[1] / "fixtures"


def test_a_node_busy_computing_ends_when_its_launcher_is_killed(tmp_path: Path) -> None:
    pid_file = tmp_path / "busy.pid"
    node = {"cmd": [sys.executable, str(FIXTURES / "busy_node.py")], "name": "busy",
            "env": [{"name": "BUSY_NODE_PID_FILE", "value": str(pid_file)}]}
    path = tmp_path / "busy.yaml"
    path.write_text(yaml.safe_dump({"launch": [{"node": node}]}))
    launcher = subprocess.Popen([sys.executable, "-m", "vibrissa.cli.launch", str(path)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    pid = None
    try:
        wait_for(lambda: pid_file.exists() and pid_file.read_text() != "", "the node to run")
        pid = int(pid_file.read_text())
        wait_for(lambda: cpu_seconds(pid) > 1.0, "the node to be computing")
        launcher.send_signal(signal.SIGKILL)
        launcher.wait(timeout=60)
        killed = time.monotonic()
        wait_for(lambda: not alive(pid), "the orphaned node to end")
        assert time.monotonic() - killed < ORPHAN_GRACE_S + 60.0
    finally:
        if launcher.poll() is None:
            launcher.kill()
        if pid is not None and alive(pid):
            os.killpg(pid, signal.SIGKILL)
