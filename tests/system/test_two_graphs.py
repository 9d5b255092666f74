"""Two graphs on one machine: a tool or a node started without ``--domain`` says which graph
it talks to (launch file, start, user) and names the other; the launch that moved off its
domain says on its summary how tools reach it."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.system.test_discovery import Launch, env_for, graph_file, tool
from vibrissa.wire.transport import running_graphs

DOMAIN = 3000 + os.getpid() % 500 * 4  # +0..+1; away from the other system tests' ranges
ISO = r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d[+-]\d\d:\d\d"


def named(domain: int, path: Path, pid: int) -> str:
    """A regex for the graph on ``domain``: its launch file, start, user and launcher pid."""
    return rf"domain {domain} \({re.escape(str(path))}, started {ISO} by \S+, pid {pid}\)"


def hand_started_node_says(env: dict[str, str], pattern: str) -> None:
    """Start a reconstructor by hand and wait for a line of its stderr matching ``pattern``."""
    proc = subprocess.Popen([sys.executable, "-m", "vibrissa.nodes.reconstructor", "--name",
                             "by_hand", "--namespace", "/hand"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stderr or ()), daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 60.0
        while not any(re.search(pattern, line) for line in lines):
            if proc.poll() is not None or time.monotonic() > deadline:
                reader.join(5)
                pytest.fail(f"no line matching {pattern!r} from the node:\n{''.join(lines)}")
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_tools_and_nodes_say_which_of_two_graphs_they_talk_to(tmp_path: Path) -> None:
    env = env_for(DOMAIN)  # a user's default domain, held by the first graph
    file_a, file_b = graph_file(tmp_path, "/graph_a"), graph_file(tmp_path, "/graph_b")
    first = Launch(file_a, env)
    second = None
    try:
        first.wait_line(rf"proxy: .*\(domain {DOMAIN};")
        first.wait_line(r"started 'reconstructor'")
        second = Launch(file_b, env)
        second.wait_line(rf"this graph runs on domain {DOMAIN + 1}")
        second.wait_line(r"started 'reconstructor'")
        this = named(DOMAIN, file_a, first.proc.pid)
        other = named(DOMAIN + 1, file_b, second.proc.pid)
        note = rf"graphs run on this machine; talking to the one on {this} \(others: (.*; )?{other}"

        listed = tool(env, "topic", "list", "--listen", "2")
        assert listed.returncode == 0, listed.stderr
        assert "/graph_a/wrench" in listed.stdout and "/graph_b" not in listed.stdout
        assert re.search(rf"^vibrissa topic list: \d+ {note}", listed.stderr, re.M), listed.stderr
        assert "pass --domain N (or VIBRISSA_DOMAIN_ID=N) for another" in listed.stderr

        echoed = tool(env, "topic", "echo", "/vibrissa/status", "-n", "1", "--timeout", "30")
        assert echoed.returncode == 0, echoed.stderr
        assert "# /vibrissa/status [vibrissa/NodeStatus]" in echoed.stdout
        assert re.search(rf"^vibrissa topic echo: \d+ {note}", echoed.stderr, re.M)
        assert "nothing on" not in echoed.stderr, echoed.stderr

        rate = tool(env, "topic", "hz", "/vibrissa/status", "--duration", "1.5")
        assert rate.returncode == 0, rate.stderr
        assert re.search(rf"^vibrissa topic hz: \d+ {note}", rate.stderr, re.M), rate.stderr

        hand_started_node_says(env, rf"/hand/by_hand: \d+ {note}.*; start it with "
                                    r"VIBRISSA_DOMAIN_ID=N for another")

        named_graph = tool(env, "topic", "list", "--listen", "1", "--domain", str(DOMAIN + 1))
        assert named_graph.returncode == 0, named_graph.stderr
        assert "/graph_b/wrench" in named_graph.stdout
        assert "graphs run on this machine" not in named_graph.stderr  # the user chose it
    finally:
        codes = [launch.stop() for launch in (second, first) if launch is not None]
    assert codes == [128 + signal.SIGINT] * 2
    assert second is not None
    moved = "".join(second.err)
    assert (f"[launch] summary: domain {DOMAIN + 1} (tools: --domain {DOMAIN + 1} or "
            f"VIBRISSA_DOMAIN_ID={DOMAIN + 1})\n") in moved, moved
    assert "[launch] summary:\n" in "".join(first.err)  # where tools find it without flags
    pids = {record.pid for record in running_graphs()}
    assert first.proc.pid not in pids and second.proc.pid not in pids  # records removed
